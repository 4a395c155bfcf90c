/* aobake._kernels: what its C files share.  One extension module, one C file per stage,
 * each mirroring the Python module whose numpy formulation is its reference (the file's
 * own comment says which); _kernels.c holds the module's method table.
 *
 * No numpy C API: arrays arrive through the buffer protocol, so the build needs only a C
 * compiler and Python's headers.  setup.py compiles every file with -ffp-contract=off, so
 * no multiply-add is fused (numpy never fuses).
 */
#ifndef AOBAKE_KERNELS_H
#define AOBAKE_KERNELS_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>

/* Check a buffer: C-contiguous, given item size, exactly `count` items. */
static inline int check(Py_buffer *b, const char *name, Py_ssize_t itemsize, Py_ssize_t count)
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

/* splitmix64 finaliser, as aobake.rng.mix (wrapping uint64 arithmetic). */
static inline uint64_t mix(uint64_t x)
{
    x ^= x >> 30;
    x *= 0xBF58476D1CE4E5B9ULL;
    x ^= x >> 27;
    x *= 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
}

/* The 32 bits of x in reverse order (aobake.samplers.sobol.reverse_bits). */
static inline uint32_t reverse32(uint32_t x)
{
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4);
    x = ((x >> 8) & 0x00FF00FFu) | ((x & 0x00FF00FFu) << 8);
    return (x >> 16) | (x << 16);
}

/* The scramble of Owen-scrambled Sobol points on bit-reversed values, still reversed
 * (Burley 2020): + seed, then Laine and Karras' permutation (aobake.samplers.joint._permute,
 * aobake.samplers.sobol.owen_scramble_reversed). */
static inline uint32_t lk_permute(uint32_t x, uint32_t seed)
{
    x += seed;
    x ^= x * 0x6C50B47Cu;
    x ^= x * 0xB82F1E52u;
    x ^= x * 0xC7AFE638u;
    x ^= x * 0x8D22F6E6u;
    return x;
}

/* np.cross of two 3-vectors: (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0), each product
 * rounded, then the difference (numpy's order; no fused multiply-add, see setup.py). */
static inline void cross3(const double a[3], const double b[3], double out[3])
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* Every one of n indices is in 0..count-1 (else a kernel declines and numpy, which raises,
 * says what is wrong). */
static inline int indices_in_range(const int64_t *index, Py_ssize_t n, Py_ssize_t count)
{
    for (Py_ssize_t i = 0; i < n; ++i)
        if (index[i] < 0 || index[i] >= count)
            return 0;
    return 1;
}

/* At most this many threads in a kernel that splits its rows among threads (the seam
 * system's assembly and the conjugate gradients). */
#define MAX_THREADS 16

/* _sparse.c: checks a CSR pattern of n rows (see there); -1 with an exception set. */
int aobake_check_csr(const int64_t *indptr, const int32_t *indices, Py_ssize_t n,
                     Py_ssize_t nnz, int nonempty);

/* _rays.c: the rays of k points (fill_rays' loop; see there). */
void aobake_ray_loop(const float *o, const double *n, const uint64_t *keys, const uint32_t *tb,
                     int sampler, int weighting, Py_ssize_t nx, Py_ssize_t ny, Py_ssize_t k,
                     Py_ssize_t R, Py_ssize_t js, Py_ssize_t mp, float *oo, float *od);

/* The module's functions (the method table in _kernels.c), by file. */
PyObject *fill_rays(PyObject *self, PyObject *args);        /* _rays.c */
PyObject *pixel_rays(PyObject *self, PyObject *args);       /* _pixels.c */
PyObject *box_rays(PyObject *self, PyObject *args);         /* _pixels.c */
PyObject *row_counts(PyObject *self, PyObject *args);       /* _counts.c */
PyObject *obj_floats(PyObject *self, PyObject *args);       /* _obj.c */
PyObject *obj_corners(PyObject *self, PyObject *args);      /* _obj.c */
PyObject *orient_terms(PyObject *self, PyObject *args);     /* _orient.c */
PyObject *orient_volumes(PyObject *self, PyObject *args);   /* _orient.c */
PyObject *raster_rows(PyObject *self, PyObject *args);      /* _raster.c */
PyObject *surface_interp(PyObject *self, PyObject *args);   /* _surface.c */
PyObject *surface_shading(PyObject *self, PyObject *args);  /* _surface.c */
PyObject *seam_pattern(PyObject *self, PyObject *args);     /* _seams.c */
PyObject *seam_values(PyObject *self, PyObject *args);      /* _seams.c */
PyObject *seam_csr_cg(PyObject *self, PyObject *args);      /* _sparse.c */
PyObject *dilate_rings(PyObject *self, PyObject *args);     /* _post.c */
PyObject *radix_argsort(PyObject *self, PyObject *args);    /* _sort.c */
PyObject *chart_marks(PyObject *self, PyObject *args);      /* _pack.c */
PyObject *pack_charts(PyObject *self, PyObject *args);      /* _pack.c */
PyObject *parity_union_find(PyObject *self, PyObject *args); /* _unionfind.c */
PyObject *triangle_normals(PyObject *self, PyObject *args);  /* _normals.c */
PyObject *vertex_normal_sums(PyObject *self, PyObject *args); /* _normals.c */

#endif
