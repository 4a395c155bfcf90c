/* aobake._kernels, the per-face terms of aobake.repair.orient (the winding check), compiled.
 *
 * Every operation is numpy's, in numpy's order (setup.py: no fused multiply-adds):
 *   - np.cross(e1, e2): (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0), each product
 *     rounded, then the difference (as _normals.c);
 *   - np.linalg.norm(v, axis=1): sqrt((x x + y y) + z z);
 *   - a sum or mean over a face's three corners (axis 1 of an (m, 3, ...) gather):
 *     (c0 + c1) + c2, the mean that sum / 3;
 *   - np.einsum("ij,ij->i", a, b) of three columns: (a0 b0 + a2 b2) + a1 b1 (numpy's
 *     sum-of-products kernel pairs them so; tests/test_repair.py checks against numpy);
 *   - both start numpy's sum from +0.0, so a sum of negative zeros is +0.0, never -0.0:
 *     "+ 0.0" after each sum here (it changes nothing else: x + 0 is x for x != -0).
 */
#include "_kernels.h"

#include <math.h>

static inline double dot3(const double a[3], const double b[3])
{
    return ((a[0] * b[0] + a[2] * b[2]) + a[1] * b[1]) + 0.0;
}

/* orient_terms(vertices, corners, normals, out_area, out_mean, out_agree) -> bool
 *
 * vertices (v, 3) float64, corners (m, 3) int64 in 0..v-1, normals (v, 3) float64 or
 * empty; writes out_area (m,) half the cross product's length, out_mean (3, m) the mean
 * corner (coordinate-major), and where normals are given out_agree (m,) the cross product
 * dotted with the sum of the corners' normals.  False, nothing to trust written, when an
 * index is out of range (the caller's numpy path then raises).
 */
PyObject *orient_terms(PyObject *self, PyObject *args)
{
    Py_buffer bv = {0}, bc = {0}, bn = {0}, ba = {0}, bm = {0}, bg = {0};
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*w*w*w*", &bv, &bc, &bn, &ba, &bm, &bg))
        return NULL;
    {
        const Py_ssize_t nv = bv.len / 24, m = bc.len / 24;
        const int voting = bn.len != 0;
        if (check(&bv, "vertices", 8, 3 * nv) || check(&bc, "corners", 8, 3 * m) ||
            (voting && check(&bn, "normals", 8, 3 * nv)) || check(&ba, "out_area", 8, m) ||
            check(&bm, "out_mean", 8, 3 * m) || (voting && check(&bg, "out_agree", 8, m)))
            goto done;
        const double *vertices = bv.buf, *normals = bn.buf;
        const int64_t *corners = bc.buf;
        double *area = ba.buf, *mean = bm.buf, *agree = bg.buf;
        int ok;
        Py_BEGIN_ALLOW_THREADS
        ok = indices_in_range(corners, 3 * m, nv);
        for (Py_ssize_t f = 0; ok && f < m; ++f) {
            const double *p0 = vertices + 3 * corners[3 * f], *p1 = vertices + 3 * corners[3 * f + 1],
                         *p2 = vertices + 3 * corners[3 * f + 2];
            const double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
            const double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
            double cr[3];
            cross3(e1, e2, cr);
            area[f] = 0.5 * sqrt((cr[0] * cr[0] + cr[1] * cr[1]) + cr[2] * cr[2]);
            for (int k = 0; k < 3; ++k)
                mean[k * m + f] = (((p0[k] + p1[k]) + p2[k]) + 0.0) / 3.0;
            if (voting) {
                const double *n0 = normals + 3 * corners[3 * f], *n1 = normals + 3 * corners[3 * f + 1],
                             *n2 = normals + 3 * corners[3 * f + 2];
                const double sum[3] = {((n0[0] + n1[0]) + n2[0]) + 0.0,
                                       ((n0[1] + n1[1]) + n2[1]) + 0.0,
                                       ((n0[2] + n1[2]) + n2[2]) + 0.0};
                agree[f] = dot3(cr, sum);
            }
        }
        Py_END_ALLOW_THREADS
        result = PyBool_FromLong(ok);
    }

done:
    PyBuffer_Release(&bv); PyBuffer_Release(&bc); PyBuffer_Release(&bn);
    PyBuffer_Release(&ba); PyBuffer_Release(&bm); PyBuffer_Release(&bg);
    return result;
}

/* orient_volumes(vertices, corners, centre, comp, out_det) -> bool
 *
 * vertices (v, 3) float64, corners (m, 3) int64 in 0..v-1, centre (c, 3) float64, comp
 * (m,) int64 in 0..c-1; writes out_det (m,): the determinant of the face's corners
 * relative to its component's centre, r0 . (r1 x r2).  False as orient_terms.
 */
PyObject *orient_volumes(PyObject *self, PyObject *args)
{
    Py_buffer bv = {0}, bc = {0}, be = {0}, bk = {0}, bd = {0};
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*", &bv, &bc, &be, &bk, &bd))
        return NULL;
    {
        const Py_ssize_t nv = bv.len / 24, m = bc.len / 24, nc = be.len / 24;
        if (check(&bv, "vertices", 8, 3 * nv) || check(&bc, "corners", 8, 3 * m) ||
            check(&be, "centre", 8, 3 * nc) || check(&bk, "comp", 8, m) ||
            check(&bd, "out_det", 8, m))
            goto done;
        const double *vertices = bv.buf, *centre = be.buf;
        const int64_t *corners = bc.buf, *comp = bk.buf;
        double *det = bd.buf;
        int ok;
        Py_BEGIN_ALLOW_THREADS
        ok = indices_in_range(corners, 3 * m, nv) && indices_in_range(comp, m, nc);
        for (Py_ssize_t f = 0; ok && f < m; ++f) {
            const double *c = centre + 3 * comp[f];
            double rel[3][3];
            for (int q = 0; q < 3; ++q) {
                const double *p = vertices + 3 * corners[3 * f + q];
                for (int k = 0; k < 3; ++k)
                    rel[q][k] = p[k] - c[k];
            }
            double cr[3];
            cross3(rel[1], rel[2], cr);
            det[f] = dot3(rel[0], cr);
        }
        Py_END_ALLOW_THREADS
        result = PyBool_FromLong(ok);
    }

done:
    PyBuffer_Release(&bv); PyBuffer_Release(&bc); PyBuffer_Release(&be);
    PyBuffer_Release(&bk); PyBuffer_Release(&bd);
    return result;
}
