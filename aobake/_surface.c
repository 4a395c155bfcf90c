/* aobake._kernels, lightmap sample points: aobake.targets.texels.surface, compiled
 * (its numpy formulation is the reference: the same bits). */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

/* surface_interp(positions, normals, faces, face, bary, out_points, out_normals, out_length)
 *
 * aobake.targets.texels.surface's interpolation at s samples, operation for operation:
 * point = (b0 p[c0] + b1 p[c1]) + b2 p[c2] per coordinate (faces[face] = c), the same for
 * the vertex normals, then the normal's length sqrt((x^2 + y^2) + z^2) (np.linalg.norm's
 * order) and the unit normal (zero where the length is 0 or not finite: vectors.normalize).
 * positions, normals (v, 3) float64 (normals may be empty: then out_normals and out_length
 * are not touched), faces (f, 3) int64, face (s,) int64, bary (s, 3) float64;
 * out_points, out_normals (s, 3) float64, out_length (s,) float64 written.
 */
PyObject *surface_interp(PyObject *self, PyObject *args)
{
    Py_buffer bp = {0}, bn = {0}, bf = {0}, bface = {0}, bb = {0}, bop = {0}, bon = {0}, bol = {0};
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*w*w*w*", &bp, &bn, &bf, &bface, &bb, &bop, &bon, &bol))
        return NULL;
    {
        const Py_ssize_t v3 = bp.len / 8, f3 = bf.len / 8, s = bface.len / 8;
        const int with_normals = bn.len > 0;
        if (v3 % 3 || f3 % 3 || check(&bp, "positions", 8, v3) || check(&bf, "faces", 8, f3) ||
            check(&bface, "face", 8, s) || check(&bb, "bary", 8, 3 * s) ||
            check(&bop, "out_points", 8, 3 * s) ||
            (with_normals && (check(&bn, "normals", 8, v3) || check(&bon, "out_normals", 8, 3 * s) ||
                              check(&bol, "out_length", 8, s)))) {
            if (!PyErr_Occurred())
                PyErr_SetString(PyExc_ValueError, "rows must have 3 columns");
            goto done;
        }
        const double *P = bp.buf, *N = bn.buf, *B = bb.buf;
        const int64_t *F = bf.buf, *face = bface.buf;
        double *op = bop.buf, *on = bon.buf, *ol = bol.buf;
        const int64_t n_faces = f3 / 3, n_vertices = v3 / 3;
        for (Py_ssize_t i = 0; i < s; ++i)
            if (face[i] < 0 || face[i] >= n_faces) {
                PyErr_SetString(PyExc_IndexError, "face index out of range");
                goto done;
            }
        for (Py_ssize_t i = 0; i < f3; ++i)
            if (F[i] < 0 || F[i] >= n_vertices) {
                PyErr_SetString(PyExc_IndexError, "vertex index out of range");
                goto done;
            }
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < s; ++i) {
            const int64_t *c = F + 3 * face[i];
            const double *b = B + 3 * i;
            for (int d = 0; d < 3; ++d)
                op[3 * i + d] = (b[0] * P[3 * c[0] + d] + b[1] * P[3 * c[1] + d])
                                + b[2] * P[3 * c[2] + d];
            if (!with_normals)
                continue;
            double n[3];
            for (int d = 0; d < 3; ++d)
                n[d] = (b[0] * N[3 * c[0] + d] + b[1] * N[3 * c[1] + d]) + b[2] * N[3 * c[2] + d];
            const double length = sqrt((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2]);
            const int ok = isfinite(length) && length > 0;
            for (int d = 0; d < 3; ++d)
                on[3 * i + d] = ok ? n[d] / length : 0.0;
            ol[i] = length;
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&bp); PyBuffer_Release(&bn); PyBuffer_Release(&bf); PyBuffer_Release(&bface);
    PyBuffer_Release(&bb); PyBuffer_Release(&bop); PyBuffer_Release(&bon); PyBuffer_Release(&bol);
    return result;
}

/* surface_shading(face, unit, has_face, turned, normals, length, out) -> (fixed, turned)
 *
 * aobake.targets.texels.surface.surface_points' choice of shading normal, per sample i of
 * face f = face[i] (see there): unit (F, 3) float64 the unit face normals, has_face and
 * turned (F,) bool, normals (s, 3) the unit interpolated normals (zero where undefined) and
 * length (s,) their lengths before normalising.  On a face not turned against its vertex
 * normals, the face normal where the interpolated one is zero or points against it
 * ((n0 f0 + n1 f1) + n2 f2 <= 0, the reference's order); on a turned face, minus the face
 * normal where it is zero; else the interpolated one.  Returns how many samples took a face
 * normal, and how many lie on turned faces. */
PyObject *surface_shading(PyObject *self, PyObject *args)
{
    Py_buffer bface = {0}, bunit = {0}, bhas = {0}, bturned = {0}, bn = {0}, blen = {0}, bout = {0};
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*w*", &bface, &bunit, &bhas, &bturned, &bn, &blen,
                          &bout))
        return NULL;
    {
        const Py_ssize_t s = bface.len / 8, faces = bhas.len;
        if (check(&bface, "face", 8, s) || check(&bunit, "unit", 8, 3 * faces) ||
            check(&bturned, "turned", 1, faces) || check(&bn, "normals", 8, 3 * s) ||
            check(&blen, "length", 8, s) || check(&bout, "out", 8, 3 * s))
            goto done;
        const int64_t *face = bface.buf;
        const double *unit = bunit.buf, *n = bn.buf, *length = blen.buf;
        const uint8_t *has = bhas.buf, *turned = bturned.buf;
        double *out = bout.buf;
        for (Py_ssize_t i = 0; i < s; ++i)
            if (face[i] < 0 || face[i] >= faces) {
                PyErr_SetString(PyExc_IndexError, "face index out of range");
                goto done;
            }
        Py_ssize_t fixed = 0, on_turned = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < s; ++i) {
            const double *f = unit + 3 * face[i], *ni = n + 3 * i;
            const int zero = length[i] == 0.0, against = turned[face[i]] != 0;
            double sign = 0.0;  /* 0: the interpolated normal; +-1: +-the face normal */
            if (!against) {
                if (has[face[i]] && (zero || (ni[0] * f[0] + ni[1] * f[1]) + ni[2] * f[2] <= 0.0))
                    sign = 1.0;
            } else if (zero) {
                sign = -1.0;
            }
            on_turned += against;
            fixed += sign != 0.0;
            for (int d = 0; d < 3; ++d)
                out[3 * i + d] = sign > 0.0 ? f[d] : sign < 0.0 ? -f[d] : ni[d];
        }
        Py_END_ALLOW_THREADS
        result = Py_BuildValue("nn", fixed, on_turned);
    }
done:
    PyBuffer_Release(&bface); PyBuffer_Release(&bunit); PyBuffer_Release(&bhas);
    PyBuffer_Release(&bturned); PyBuffer_Release(&bn); PyBuffer_Release(&blen);
    PyBuffer_Release(&bout);
    return result;
}
