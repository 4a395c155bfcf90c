/* aobake._kernels, the face and vertex normals of aobake.scene (face_normals,
 * vertex_normals, make_scene's face normals and areas), compiled.
 *
 * Every operation is numpy's, in numpy's order (setup.py: no fused multiply-adds):
 *   - np.cross(e1, e2) of e1 = p1 - p0, e2 = p2 - p0: (a1 b2 - a2 b1, a2 b0 - a0 b2,
 *     a0 b1 - a1 b0), each product rounded, then the difference;
 *   - aobake.vectors.normalize: length sqrt((x x + y y) + z z), the row divided by it
 *     where it is finite and > 0, else a zero row;
 *   - scene._corner_cosines: the dot of two unit edges summed (x x' + z z') + y y', then
 *     clipped to [-1, 1];
 *   - np.bincount's accumulation: corner 0 of every face, then corner 1, then corner 2,
 *     each added to its vertex's running sum (from 0.0) in that sequence.
 * The arccos of the cosines is numpy's own (np.arccos between the two kernels): numpy's
 * float64 arccos is not the C library's everywhere (AVX-512 builds use their own).
 */
#include "_kernels.h"

#include <math.h>
#include <stdint.h>

/* aobake.vectors.normalize of one row: out = v / |v|, or zero; returns |v|. */
static inline double unit3(const double v[3], double out[3])
{
    const double length = sqrt((v[0] * v[0] + v[1] * v[1]) + v[2] * v[2]);
    if (isfinite(length) && length > 0) {
        out[0] = v[0] / length;
        out[1] = v[1] / length;
        out[2] = v[2] / length;
    } else {
        out[0] = out[1] = out[2] = 0.0;
    }
    return length;
}


/* triangle_normals(vertices, faces, out_unit, out_length, out_cross, out_cos) -> bool
 *
 * vertices (v, 3) float64, faces (f, 3) int64; writes out_unit (f, 3) the unit face
 * normals (face_normals), out_length (f,) the cross products' lengths (normalize's, which
 * are np.linalg.norm's bits), and where they are not empty out_cross (f, 3) the cross
 * products and out_cos (3, f) each corner's clipped cosine (corner-major, as
 * vertex_normals's angles).  False, with nothing to trust written, when a face index is
 * not in 0..v-1 (the caller's numpy path then says what is wrong).
 */
PyObject *triangle_normals(PyObject *self, PyObject *args)
{
    Py_buffer bv = {0}, bf = {0}, bu = {0}, bl = {0}, bc = {0}, bk = {0};
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*w*w*w*w*", &bv, &bf, &bu, &bl, &bc, &bk))
        return NULL;
    {
        const Py_ssize_t nv = bv.len / 24, nf = bf.len / 24;
        const int want_cross = bc.len != 0, want_cos = bk.len != 0;
        if (check(&bv, "vertices", 8, 3 * nv) || check(&bf, "faces", 8, 3 * nf) ||
            check(&bu, "out_unit", 8, 3 * nf) || check(&bl, "out_length", 8, nf) ||
            (want_cross && check(&bc, "out_cross", 8, 3 * nf)) ||
            (want_cos && check(&bk, "out_cos", 8, 3 * nf)))
            goto done;
        const double *vertices = bv.buf;
        const int64_t *faces = bf.buf;
        double *unit = bu.buf, *length = bl.buf, *out_cross = bc.buf, *cosine = bk.buf;
        int ok;
        Py_BEGIN_ALLOW_THREADS
        ok = indices_in_range(faces, 3 * nf, nv);
        for (Py_ssize_t f = 0; ok && f < nf; ++f) {
            const double *p[3];
            for (int c = 0; c < 3; ++c)
                p[c] = vertices + 3 * faces[3 * f + c];
            double e1[3], e2[3], cr[3];
            for (int d = 0; d < 3; ++d) {
                e1[d] = p[1][d] - p[0][d];
                e2[d] = p[2][d] - p[0][d];
            }
            cross3(e1, e2, cr);
            length[f] = unit3(cr, unit + 3 * f);
            if (want_cross)
                for (int d = 0; d < 3; ++d)
                    out_cross[3 * f + d] = cr[d];
            if (want_cos)
                for (int c = 0; c < 3; ++c) {
                    const double *o = p[c], *q = p[(c + 1) % 3], *r = p[(c + 2) % 3];
                    const double ea[3] = {q[0] - o[0], q[1] - o[1], q[2] - o[2]};
                    const double eb[3] = {r[0] - o[0], r[1] - o[1], r[2] - o[2]};
                    double a[3], b[3];
                    unit3(ea, a);
                    unit3(eb, b);
                    double dot = (a[0] * b[0] + a[2] * b[2]) + a[1] * b[1];
                    /* np.clip: the cosine is finite (unit rows or zero rows) */
                    dot = dot < -1.0 ? -1.0 : (dot > 1.0 ? 1.0 : dot);
                    cosine[(Py_ssize_t)c * nf + f] = dot;
                }
        }
        Py_END_ALLOW_THREADS
        result = PyBool_FromLong(ok);
    }

done:
    PyBuffer_Release(&bv); PyBuffer_Release(&bf); PyBuffer_Release(&bu);
    PyBuffer_Release(&bl); PyBuffer_Release(&bc); PyBuffer_Release(&bk);
    return result;
}

/* vertex_normal_sums(faces, rows, angles, out) -> bool
 *
 * faces (f, 3) int64 in 0..v-1 (checked: False, out not to be trusted, otherwise), rows
 * (f, 3) float64, angles (3, f) float64 or empty, out (v, 3) float64 written: the sum over
 * the corners at each vertex of rows[face] * angles[corner, face] (angle weighting: rows
 * the unit face normals) or of rows[face] (area weighting: rows the cross products),
 * added corner 0 of every face first, then corner 1, then corner 2 (vertex_normals's
 * bincount), then each sum normalised (zero where its length is zero or not finite).
 */
PyObject *vertex_normal_sums(PyObject *self, PyObject *args)
{
    Py_buffer bf = {0}, br = {0}, ba = {0}, bo = {0};
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*w*", &bf, &br, &ba, &bo))
        return NULL;
    {
        const Py_ssize_t nf = bf.len / 24, nv = bo.len / 24;
        const int weighted = ba.len != 0;
        if (check(&bf, "faces", 8, 3 * nf) || check(&br, "rows", 8, 3 * nf) ||
            (weighted && check(&ba, "angles", 8, 3 * nf)) || check(&bo, "out", 8, 3 * nv))
            goto done;
        const int64_t *faces = bf.buf;
        const double *rows = br.buf, *angles = ba.buf;
        double *out = bo.buf;
        int ok;
        Py_BEGIN_ALLOW_THREADS
        ok = indices_in_range(faces, 3 * nf, nv);
        if (ok) {
            for (Py_ssize_t i = 0; i < 3 * nv; ++i)
                out[i] = 0.0;
            for (int c = 0; c < 3; ++c)
                for (Py_ssize_t f = 0; f < nf; ++f) {
                    double *sum = out + 3 * faces[3 * f + c];
                    const double *row = rows + 3 * f;
                    if (weighted) {
                        const double angle = angles[(Py_ssize_t)c * nf + f];
                        sum[0] += row[0] * angle;
                        sum[1] += row[1] * angle;
                        sum[2] += row[2] * angle;
                    } else {
                        sum[0] += row[0];
                        sum[1] += row[1];
                        sum[2] += row[2];
                    }
                }
            for (Py_ssize_t v = 0; v < nv; ++v) {
                const double s[3] = {out[3 * v], out[3 * v + 1], out[3 * v + 2]};
                unit3(s, out + 3 * v);
            }
        }
        Py_END_ALLOW_THREADS
        result = PyBool_FromLong(ok);
    }

done:
    PyBuffer_Release(&bf); PyBuffer_Release(&br); PyBuffer_Release(&ba); PyBuffer_Release(&bo);
    return result;
}
