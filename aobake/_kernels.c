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
 * the same precision as its numpy counterpart (double for the frame and its
 * rotation, float for the direction sum), evaluated left to right; cos and sin
 * come from the C library, which the numpy path calls through math.cos/sin.
 * setup.py compiles with -ffp-contract=off so no multiply-add is fused (numpy
 * never fuses).
 *
 * No numpy C API: arrays arrive through the buffer protocol, so the build
 * needs only a C compiler and Python's headers.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
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

/* splitmix64 finaliser, as aobake.samplers._mix (wrapping uint64 arithmetic). */
static inline uint64_t mix(uint64_t x)
{
    x ^= x >> 30;
    x *= 0xBF58476D1CE4E5B9ULL;
    x ^= x >> 27;
    x *= 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
}

/* fill_rays(origins, normals, ids, key, dim_salt, local, k, R, m, out_origins, out_directions)
 *
 * origins   (k, 3)    float32   ray origin of each point
 * normals   (k, 3)    float64   unit normal of each point
 * ids       (k,)      int64     point ids
 * key, dim_salt       uint64    aobake.samplers.hash_uniform's stream key and
 *                               dimension salt for the azimuth shift
 * local     (R, m, 3) float32   local directions (x, y, z), z along the normal
 * out_origins    (k*R*m, 3) float32  written: origins[p] repeated R*m times
 * out_directions (k*R*m, 3) float32  written: x T' + y B' + z N
 *
 * Per point and replicate g, as aobake.rays.RayGenerator's numpy path does it:
 *   u   = hash_uniform(seed, SHIFT stream, id * R + g, dim 1)
 *   phi = (2 pi) u;  c, s = cos(phi), sin(phi)       (C library, as math.cos)
 *   (T, B) = aobake.warp.frames(N)                   (Duff et al. 2017)
 *   T' = float(c T + s B), B' = float(c B - s T), N' = float(N)
 */
static PyObject *fill_rays(PyObject *self, PyObject *args)
{
    Py_buffer org = {0}, nrm = {0}, idb = {0}, loc = {0}, out_o = {0}, out_d = {0};
    unsigned long long key, salt;
    Py_ssize_t k, R, m;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*KKy*nnnw*w*", &org, &nrm, &idb, &key, &salt, &loc,
                          &k, &R, &m, &out_o, &out_d))
        return NULL;
    if (k < 0 || R < 0 || m < 0) {
        PyErr_SetString(PyExc_ValueError, "negative size");
        goto done;
    }
    if (check(&org, "origins", 4, 3 * k) || check(&nrm, "normals", 8, 3 * k) ||
        check(&idb, "ids", 8, k) || check(&loc, "local", 4, R * m * 3) ||
        check(&out_o, "out_origins", 4, k * R * m * 3) ||
        check(&out_d, "out_directions", 4, k * R * m * 3))
        goto done;

    {
        const float *o = (const float *)org.buf, *l = (const float *)loc.buf;
        const double *n = (const double *)nrm.buf;
        const int64_t *ids = (const int64_t *)idb.buf;
        float *oo = (float *)out_o.buf, *od = (float *)out_d.buf;
        const double two_pi = 2.0 * 3.141592653589793;  /* Python's 2.0 * math.pi */

        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t p = 0; p < k; ++p) {
            const double x = n[3 * p], y = n[3 * p + 1], z = n[3 * p + 2];
            /* aobake.warp.frames, operation for operation. */
            const double sign = z >= 0.0 ? 1.0 : -1.0;
            const double a = -1.0 / (sign + z);
            const double b = x * y * a;
            const double t[3] = {1.0 + sign * x * x * a, sign * b, -sign * x};
            const double bt[3] = {b, sign + y * y * a, -y};
            const float ox = o[3 * p], oy = o[3 * p + 1], oz = o[3 * p + 2];
            const float n0 = (float)x, n1 = (float)y, n2 = (float)z;
            for (Py_ssize_t g = 0; g < R; ++g) {
                const uint64_t index = (uint64_t)(ids[p] * (int64_t)R + (int64_t)g);
                const uint64_t h = mix(mix((uint64_t)key ^ index) + (uint64_t)salt);
                const double phi = two_pi * ((double)(h >> 11) * 0x1p-53);
                const double cg = cos(phi), sg = sin(phi);
                /* Rows of the rotated frame, rounded to float32 once (as numpy stores them). */
                const float t0 = (float)(cg * t[0] + sg * bt[0]);
                const float t1 = (float)(cg * t[1] + sg * bt[1]);
                const float t2 = (float)(cg * t[2] + sg * bt[2]);
                const float b0 = (float)(cg * bt[0] - sg * t[0]);
                const float b1 = (float)(cg * bt[1] - sg * t[1]);
                const float b2 = (float)(cg * bt[2] - sg * t[2]);
                const float *lg = l + 3 * m * g;
                for (Py_ssize_t j = 0; j < m; ++j) {
                    const float lx = lg[3 * j], ly = lg[3 * j + 1], lz = lg[3 * j + 2];
                    od[0] = lx * t0 + ly * b0 + lz * n0;
                    od[1] = lx * t1 + ly * b1 + lz * n1;
                    od[2] = lx * t2 + ly * b2 + lz * n2;
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
    PyBuffer_Release(&nrm);
    PyBuffer_Release(&idb);
    PyBuffer_Release(&loc);
    PyBuffer_Release(&out_o);
    PyBuffer_Release(&out_d);
    return result;
}

/* row_counts(flags, rows, m, out)
 *
 * flags (rows * m,) bool (one byte each, 0 or 1); out (rows,) int32 written: the
 * number of nonzero flags in each row of m.  The escape counts of the AO
 * estimator: numpy's count_nonzero over a short last axis costs as much as
 * generating the rays.
 */
static PyObject *row_counts(PyObject *self, PyObject *args)
{
    Py_buffer fl = {0}, out = {0};
    Py_ssize_t rows, m;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*nnw*", &fl, &rows, &m, &out))
        return NULL;
    if (rows < 0 || m < 0) {
        PyErr_SetString(PyExc_ValueError, "negative size");
        goto done;
    }
    if (check(&fl, "flags", 1, rows * m) || check(&out, "out", 4, rows))
        goto done;
    {
        const uint8_t *f = (const uint8_t *)fl.buf;
        int32_t *c = (int32_t *)out.buf;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = 0; r < rows; ++r) {
            int32_t total = 0;
            for (Py_ssize_t j = 0; j < m; ++j)
                total += f[r * m + j] != 0;
            c[r] = total;
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&fl);
    PyBuffer_Release(&out);
    return result;
}

static PyMethodDef methods[] = {
    {"fill_rays", fill_rays, METH_VARARGS,
     "fill_rays(origins, normals, ids, key, dim_salt, local, k, R, m, out_origins, "
     "out_directions): write point-major ray origins and directions."},
    {"row_counts", row_counts, METH_VARARGS,
     "row_counts(flags, rows, m, out): nonzero flags per row of m."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "aobake._kernels",
    "Compiled per-ray kernels of aobake (see aobake.rays).", -1, methods,
};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
