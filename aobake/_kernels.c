/* aobake._kernels: the per-ray part of ray generation, compiled.
 *
 * numpy builds each chunk's rays at 10-40 Mrays/s per thread; Embree traces at
 * 3-5 Mrays/s per thread, so numpy ray generation costs 10-25% of the bake.
 * This kernel does the same arithmetic, in the same order and precision, in
 * one pass over the output, with the GIL released.  aobake.rays keeps the
 * numpy formulation as the reference (and the fallback when this extension was
 * not built); tests check the two agree bit for bit.
 *
 * Exactness: every operation below is a single IEEE-754 operation rounded in
 * the same precision as its numpy counterpart (double for the frame rotation,
 * float for the direction sum), evaluated left to right.  setup.py compiles
 * with -ffp-contract=off so no multiply-add is fused (numpy never fuses).
 *
 * No numpy C API: arrays arrive through the buffer protocol, so the build
 * needs only a C compiler and Python's headers.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

/* Check a buffer: C-contiguous, given item size, exactly `count` items. */
static int check(Py_buffer *b, const char *name, Py_ssize_t itemsize, Py_ssize_t count)
{
    if (!PyBuffer_IsContiguous(b, 'C')) {
        PyErr_Format(PyExc_ValueError, "%s must be C-contiguous", name);
        return -1;
    }
    if (b->itemsize != itemsize || b->len != itemsize * count) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd items of %zd bytes, got %zd bytes",
                     name, count, itemsize, b->len);
        return -1;
    }
    return 0;
}

/* fill_rays(origins, tangent, bitangent, normal, cos_az, sin_az, local, k, R, m,
 *           out_origins, out_directions)
 *
 * origins   (k, 3)    float32   ray origin of each point
 * tangent   (k, 3)    float64   frame of each point (unit, orthonormal with normal)
 * bitangent (k, 3)    float64
 * normal    (k, 3)    float64
 * cos_az    (k, R)    float64   cos / sin of the azimuth rotation of point p, replicate g
 * sin_az    (k, R)    float64
 * local     (R, m, 3) float32   local directions (x, y, z), z along the normal
 * out_origins    (k*R*m, 3) float32  written: origins[p] repeated R*m times
 * out_directions (k*R*m, 3) float32  written: x T' + y B' + z N with
 *     T' = float(c T + s B), B' = float(c B - s T), N' = float(N)
 */
static PyObject *fill_rays(PyObject *self, PyObject *args)
{
    Py_buffer org = {0}, tan = {0}, bit = {0}, nrm = {0}, cs = {0}, sn = {0}, loc = {0};
    Py_buffer out_o = {0}, out_d = {0};
    Py_ssize_t k, R, m;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*nnnw*w*", &org, &tan, &bit, &nrm, &cs, &sn, &loc,
                          &k, &R, &m, &out_o, &out_d))
        return NULL;
    if (k < 0 || R < 0 || m < 0) {
        PyErr_SetString(PyExc_ValueError, "negative size");
        goto done;
    }
    if (check(&org, "origins", 4, 3 * k) || check(&tan, "tangent", 8, 3 * k) ||
        check(&bit, "bitangent", 8, 3 * k) || check(&nrm, "normal", 8, 3 * k) ||
        check(&cs, "cos_az", 8, k * R) || check(&sn, "sin_az", 8, k * R) ||
        check(&loc, "local", 4, R * m * 3) || check(&out_o, "out_origins", 4, k * R * m * 3) ||
        check(&out_d, "out_directions", 4, k * R * m * 3))
        goto done;

    {
        const float *o = (const float *)org.buf, *l = (const float *)loc.buf;
        const double *t = (const double *)tan.buf, *b = (const double *)bit.buf;
        const double *n = (const double *)nrm.buf;
        const double *c = (const double *)cs.buf, *s = (const double *)sn.buf;
        float *oo = (float *)out_o.buf, *od = (float *)out_d.buf;

        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t p = 0; p < k; ++p) {
            const double *tp = t + 3 * p, *bp = b + 3 * p, *np_ = n + 3 * p;
            const float ox = o[3 * p], oy = o[3 * p + 1], oz = o[3 * p + 2];
            const float n0 = (float)np_[0], n1 = (float)np_[1], n2 = (float)np_[2];
            for (Py_ssize_t g = 0; g < R; ++g) {
                const double cg = c[p * R + g], sg = s[p * R + g];
                /* Rows of the rotated frame, rounded to float32 once (as numpy stores them). */
                const float t0 = (float)(cg * tp[0] + sg * bp[0]);
                const float t1 = (float)(cg * tp[1] + sg * bp[1]);
                const float t2 = (float)(cg * tp[2] + sg * bp[2]);
                const float b0 = (float)(cg * bp[0] - sg * tp[0]);
                const float b1 = (float)(cg * bp[1] - sg * tp[1]);
                const float b2 = (float)(cg * bp[2] - sg * tp[2]);
                const float *lg = l + 3 * m * g;
                for (Py_ssize_t j = 0; j < m; ++j) {
                    const float x = lg[3 * j], y = lg[3 * j + 1], z = lg[3 * j + 2];
                    od[0] = x * t0 + y * b0 + z * n0;
                    od[1] = x * t1 + y * b1 + z * n1;
                    od[2] = x * t2 + y * b2 + z * n2;
                    oo[0] = ox;
                    oo[1] = oy;
                    oo[2] = oz;
                    od += 3;
                    oo += 3;
                }
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&org);
    PyBuffer_Release(&tan);
    PyBuffer_Release(&bit);
    PyBuffer_Release(&nrm);
    PyBuffer_Release(&cs);
    PyBuffer_Release(&sn);
    PyBuffer_Release(&loc);
    PyBuffer_Release(&out_o);
    PyBuffer_Release(&out_d);
    return result;
}

static PyMethodDef methods[] = {
    {"fill_rays", fill_rays, METH_VARARGS,
     "fill_rays(origins, tangent, bitangent, normal, cos_az, sin_az, local, k, R, m, "
     "out_origins, out_directions): write point-major ray origins and directions."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "aobake._kernels",
    "Compiled per-ray kernels of aobake (see aobake.rays).", -1, methods,
};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
