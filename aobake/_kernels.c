/* aobake._kernels: the per-ray part of ray generation, the AO escape counts,
 * the lightmap rasteriser's per-pair tests and the seam erasure's solve, compiled.
 *
 * numpy builds each chunk's rays at 10-40 Mrays/s per thread; Embree traces at
 * 3-5 Mrays/s per thread, so numpy ray generation costs 10-25% of the bake.
 * This kernel does the same arithmetic, in the same order and precision, in
 * one pass over the output, with the GIL released.  aobake.rays keeps the
 * numpy formulation as the reference (and the fallback when this extension was
 * not built); tests check the two agree bit for bit.
 *
 * Exactness: every operation below is a single IEEE-754 operation rounded in
 * the same precision as its numpy counterpart, evaluated left to right; cos and
 * sin come from one + and * polynomial (aobake.warp.cos_sin_2pi), sqrt is
 * correctly rounded in both.
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

/* splitmix64 finaliser, as aobake.rng.mix (wrapping uint64 arithmetic). */
static inline uint64_t mix(uint64_t x)
{
    x ^= x >> 30;
    x *= 0xBF58476D1CE4E5B9ULL;
    x ^= x >> 27;
    x *= 0x94D049BB133111EBULL;
    return x ^ (x >> 31);
}

/* The samplers of aobake.samplers, sample j of the replicate with key `key`. */
#define SALT0 0x632BE59BD9B4E019ULL  /* aobake.rng.dim_salt(0) */
#define SALT1 0xC657CB37B369C032ULL  /* aobake.rng.dim_salt(1) */
#define SAMPLE_STEP 0xD1B54A32D192ED03ULL  /* aobake.samplers.base.sample_hashes */

static inline double unit53(uint64_t h) { return (double)(h >> 11) * 0x1p-53; }

static inline uint32_t reverse32(uint32_t x)
{
    x = ((x >> 1) & 0x55555555u) | ((x & 0x55555555u) << 1);
    x = ((x >> 2) & 0x33333333u) | ((x & 0x33333333u) << 2);
    x = ((x >> 4) & 0x0F0F0F0Fu) | ((x & 0x0F0F0F0Fu) << 4);
    x = ((x >> 8) & 0x00FF00FFu) | ((x & 0x00FF00FFu) << 8);
    return (x >> 16) | (x << 16);
}

/* aobake.samplers.sobol.owen_scramble_reversed (Burley 2020, Laine-Karras permutation) of a
 * bit-reversed Sobol point (the table is stored reversed: one reversal per sample saved). */
#define BLOCK 64
static inline uint32_t owen_reversed(uint32_t x, uint32_t seed)
{
    x += seed;
    x ^= x * 0x6C50B47Cu;
    x ^= x * 0xB82F1E52u;
    x ^= x * 0xC7AFE638u;
    x ^= x * 0x8D22F6E6u;
    return reverse32(x);
}

/* aobake.warp.cos_sin_2pi: + and * only, in the same order. */
/* (-1)^k / (2k+1)! and (-1)^k / (2k)!, as Python computes them (correctly rounded). */
static const double SIN_C[5] = {1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0, 1.0 / 362880.0};
static const double COS_C[6] = {1.0, -1.0 / 2.0, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0,
                                -1.0 / 3628800.0};

static inline void cos_sin_2pi(double u, double *co, double *si)
{
    const double t = u * 4.0;
    const int quadrant = (int)t;  /* t in [0, 4): truncation is floor, and vectorises */
    const double x = ((t - (double)quadrant) - 0.5) * 1.5707963267948966;
    const double x2 = x * x;
    double s = SIN_C[4], c = COS_C[5];
    for (int i = 3; i >= 0; --i)
        s = s * x2 + SIN_C[i];
    s = s * x;
    for (int i = 4; i >= 0; --i)
        c = c * x2 + COS_C[i];
    const double ca = (c - s) * 0.7071067811865476, sa = (s + c) * 0.7071067811865476;
    /* Quadrant rotation by selection and sign flips (exact), without branches. */
    const int odd = quadrant & 1, neg_c = (quadrant == 1) | (quadrant == 2), neg_s = quadrant >= 2;
    const double pc = odd ? sa : ca, ps = odd ? ca : sa;
    *co = neg_c ? -pc : pc;
    *si = neg_s ? -ps : ps;
}

/* The ray loop of fill_rays.  Compiled twice where the compiler can (GCC/clang on x86-64
 * Linux): for AVX2 and for the baseline, picked at load time by the CPU.  The AVX2 build
 * vectorises the Owen hash and the square roots (measured 15.5 -> 8.8 ns per ray); both
 * do the same IEEE operations (no contraction: -ffp-contract=off), so the rays are
 * bit-identical whichever runs. */
#if defined(__x86_64__) && defined(__linux__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("avx2", "default")))
#endif
static void ray_loop(const float *o, const double *n, const uint64_t *keys, const uint32_t *tb,
                     int sampler, int weighting, Py_ssize_t nx, Py_ssize_t ny, Py_ssize_t k,
                     Py_ssize_t R, Py_ssize_t js, Py_ssize_t mp, float *oo, float *od)
{
    const double below_one = nextafter(1.0, 0.0);
    for (Py_ssize_t p = 0; p < k; ++p) {
        const double x = n[3 * p], y = n[3 * p + 1], z = n[3 * p + 2];
        /* aobake.warp.frames, operation for operation. */
        const double sign = z >= 0.0 ? 1.0 : -1.0;
        const double a = -1.0 / (sign + z);
        const double b = x * y * a;
        const double t[3] = {1.0 + sign * x * x * a, sign * b, -sign * x};
        const double bt[3] = {b, sign + y * y * a, -y};
        const float ox = o[3 * p], oy = o[3 * p + 1], oz = o[3 * p + 2];
        for (Py_ssize_t g = 0; g < R; ++g) {
            const uint64_t key = keys[p * R + g];
            const uint32_t s0 = (uint32_t)(mix(key + SALT0) >> 32);
            const uint32_t s1 = (uint32_t)(mix(key + SALT1) >> 32);
            /* In blocks, one stage at a time: each loop is branch-free and the
             * compiler vectorises the square roots and the polynomial. */
            /* Samples js .. js + mp - 1 of the replicate (tb: their constants). */
            for (Py_ssize_t j0 = 0; j0 < mp; j0 += BLOCK) {
                const Py_ssize_t nb = mp - j0 < BLOCK ? mp - j0 : BLOCK;
                double u0[BLOCK], u1[BLOCK], r[BLOCK], zz[BLOCK], c[BLOCK], s[BLOCK];
                if (sampler == 2) {
                    for (Py_ssize_t i = 0; i < nb; ++i) {
                        u0[i] = ((double)owen_reversed(tb[2 * (j0 + i)], s0) + 0.5) * 0x1p-32;
                        u1[i] = ((double)owen_reversed(tb[2 * (j0 + i) + 1], s1) + 0.5) * 0x1p-32;
                    }
                } else {
                    for (Py_ssize_t i = 0; i < nb; ++i) {
                        const uint64_t h = mix(key + (uint64_t)(js + j0 + i + 1) * SAMPLE_STEP);
                        u0[i] = unit53(mix(h + SALT0));
                        u1[i] = unit53(mix(h + SALT1));
                    }
                    if (sampler == 1) {
                        for (Py_ssize_t i = 0; i < nb; ++i) {
                            const Py_ssize_t jj = js + j0 + i;
                            u0[i] = ((double)(jj % nx) + u0[i]) / (double)nx;
                            u1[i] = ((double)(jj / nx) + u1[i]) / (double)ny;
                            if (u0[i] > below_one) u0[i] = below_one;
                            if (u1[i] > below_one) u1[i] = below_one;
                        }
                    }
                }
                if (weighting == 0) {
                    for (Py_ssize_t i = 0; i < nb; ++i) {
                        r[i] = sqrt(u0[i]);
                        zz[i] = sqrt(1.0 - u0[i]);
                    }
                } else {
                    for (Py_ssize_t i = 0; i < nb; ++i) {
                        zz[i] = 1.0 - u0[i];
                        r[i] = sqrt(u0[i] * (2.0 - u0[i]));
                    }
                }
                for (Py_ssize_t i = 0; i < nb; ++i)
                    cos_sin_2pi(u1[i], &c[i], &s[i]);
                for (Py_ssize_t i = 0; i < nb; ++i) {
                    const double lx = r[i] * c[i], ly = r[i] * s[i];
                    od[0] = (float)((lx * t[0] + ly * bt[0]) + zz[i] * x);
                    od[1] = (float)((lx * t[1] + ly * bt[1]) + zz[i] * y);
                    od[2] = (float)((lx * t[2] + ly * bt[2]) + zz[i] * z);
                    oo[0] = ox;
                    oo[1] = oy;
                    oo[2] = oz;
                    od += 3;
                    oo += 3;
                }
            }
        }
    }
}

/* fill_rays(origins, normals, keys, table, sampler, weighting, nx, ny, k, R, m, js, mp,
 *           out_origins, out_directions)
 *
 * Samples js .. js + mp - 1 of the m of each replicate (a streamed point's piece; js = 0,
 * mp = m for a whole point).
 *
 * origins   (k, 3)    float32   ray origin of each point
 * normals   (k, 3)    float64   unit normal of each point
 * keys      (k, R)    uint64    aobake.samplers.replicate_keys
 * table     (mp, 2)   uint32    bit-reversed Sobol points js.. (sampler 2), else empty
 * sampler   0 random, 1 stratified (nx * ny = m cells), 2 sobol (Owen-scrambled)
 * weighting 0 cosine (r = sqrt(u0), z = sqrt(1 - u0)), 1 uniform (z = 1 - u0,
 *           r = sqrt(u0 (2 - u0)))
 * out_origins    (k*R*mp, 3) float32  written: origins[p] repeated R*mp times
 * out_directions (k*R*mp, 3) float32  written: float((r cos phi T + r sin phi B) + z N)
 *
 * Operation for operation as aobake.rays.RayGenerator's numpy path.
 */
static PyObject *fill_rays(PyObject *self, PyObject *args)
{
    Py_buffer org = {0}, nrm = {0}, keyb = {0}, tab = {0}, out_o = {0}, out_d = {0};
    int sampler, weighting;
    Py_ssize_t nx, ny, k, R, m, js, mp;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*iinnnnnnnw*w*", &org, &nrm, &keyb, &tab, &sampler,
                          &weighting, &nx, &ny, &k, &R, &m, &js, &mp, &out_o, &out_d))
        return NULL;
    if (k < 0 || R < 0 || m < 0 || js < 0 || mp < 0 || js + mp > m) {
        PyErr_SetString(PyExc_ValueError, "negative size");
        goto done;
    }
    if (sampler < 0 || sampler > 2 || weighting < 0 || weighting > 1 ||
        (sampler == 1 && (nx < 1 || ny < 1 || nx * ny != m))) {
        PyErr_SetString(PyExc_ValueError, "bad sampler, weighting or grid");
        goto done;
    }
    if (check(&org, "origins", 4, 3 * k) || check(&nrm, "normals", 8, 3 * k) ||
        check(&keyb, "keys", 8, k * R) || check(&tab, "table", 4, sampler == 2 ? 2 * mp : 0) ||
        check(&out_o, "out_origins", 4, k * R * mp * 3) ||
        check(&out_d, "out_directions", 4, k * R * mp * 3))
        goto done;

    {
        const float *o = (const float *)org.buf;
        const double *n = (const double *)nrm.buf;
        const uint64_t *keys = (const uint64_t *)keyb.buf;
        const uint32_t *tb = (const uint32_t *)tab.buf;
        float *oo = (float *)out_o.buf, *od = (float *)out_d.buf;

        Py_BEGIN_ALLOW_THREADS
        ray_loop(o, n, keys, tb, sampler, weighting, nx, ny, k, R, js, mp, oo, od);
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&org);
    PyBuffer_Release(&nrm);
    PyBuffer_Release(&keyb);
    PyBuffer_Release(&tab);
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

/* raster_pairs(ax, ay, dx, dy, owner, corner, vmax, t, row, col, width, n_sub, seed_key, q, g,
 *              out_centre, out_open, out_ins, out_bary)
 *
 * The per-pair tests of aobake.targets.texels._raster_chunk for n candidate
 * (triangle, texel) pairs, operation for operation (see there for the maths):
 *
 * ax, ay, dx, dy (f, 3) float64  oriented edge functions E = dx (y - ay) - dy (x - ax)
 * owner (f, 3) bool, corner (f, 3) int64, vmax (f, 2) float64
 * t, row, col (n,) int64          the pairs; width: texels per row (texel = row * width + col)
 * n_sub                          K sub-positions per texel
 * seed_key uint64                _mix64(seed ^ _SEED_SALT) of the jitter hash
 * q, g                           q * q == K: jittered q x q grid; else rank-1 lattice with g
 * out_centre (n,) bool           the texel centre is on the triangle (coverage rule)
 * out_open (n,) bool             the triangle overlaps the open texel square
 * out_ins (K, n) bool            sub-position k landed on the triangle
 * out_bary (K, n, 3) float64     its barycentrics in face-corner order (0 where not landed)
 *
 * With K = 1 the only sub-position is the centre.  With K > 1 pairs failing the
 * closed-overlap pre-filter get no landed sub-position, exactly as the numpy path,
 * which drops them before testing sub-positions.
 */
static inline double edge_value(const double *ax, const double *ay, const double *dx,
                                const double *dy, int e, double x, double y)
{
    return dx[e] * (y - ay[e]) - dy[e] * (x - ax[e]);
}

static inline int on_triangle(const double *e, const uint8_t *own)
{
    for (int i = 0; i < 3; ++i)
        if (!(e[i] > 0 || (e[i] == 0 && own[i])))
            return 0;
    return 1;
}

static inline double jitter(uint64_t seed_key, uint64_t texel, uint64_t k, uint64_t dim)
{
    const uint64_t golden = 0x9E3779B97F4A7C15ULL;
    const uint64_t key = texel * 0x100000ULL + (k * 4 + dim);
    const uint64_t h = mix(mix(key * golden + seed_key) + golden);
    return (double)(h >> 11) * (1.0 / 9007199254740992.0);
}

static PyObject *raster_pairs(PyObject *self, PyObject *args)
{
    Py_buffer bax = {0}, bay = {0}, bdx = {0}, bdy = {0}, bown = {0}, bcor = {0}, bvm = {0};
    Py_buffer bt = {0}, brow = {0}, bcol = {0}, bc = {0}, bo = {0}, bi = {0}, bb = {0};
    Py_ssize_t width, n_sub, q, g;
    unsigned long long seed_key;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*nnKnnw*w*w*w*", &bax, &bay, &bdx, &bdy,
                          &bown, &bcor, &bvm, &bt, &brow, &bcol, &width, &n_sub, &seed_key, &q, &g,
                          &bc, &bo, &bi, &bb))
        return NULL;
    {
        const Py_ssize_t f3 = bax.len / 8, n = bt.len / 8;
        if (n_sub < 1 || q < 1 || g < 0 || width < 1 || f3 % 3) {
            PyErr_SetString(PyExc_ValueError, "bad sizes");
            goto done;
        }
        if (check(&bax, "ax", 8, f3) || check(&bay, "ay", 8, f3) || check(&bdx, "dx", 8, f3) ||
            check(&bdy, "dy", 8, f3) || check(&bown, "owner", 1, f3) || check(&bcor, "corner", 8, f3) ||
            check(&bvm, "vmax", 8, f3 / 3 * 2) || check(&bt, "t", 8, n) || check(&brow, "row", 8, n) ||
            check(&bcol, "col", 8, n) || check(&bc, "out_centre", 1, n) || check(&bo, "out_open", 1, n) ||
            check(&bi, "out_ins", 1, n_sub * n) || check(&bb, "out_bary", 8, n_sub * n * 3))
            goto done;
        const double *AX = bax.buf, *AY = bay.buf, *DX = bdx.buf, *DY = bdy.buf, *VM = bvm.buf;
        const uint8_t *OWN = bown.buf;
        const int64_t *COR = bcor.buf, *T = bt.buf, *ROW = brow.buf, *COL = bcol.buf;
        uint8_t *centre = bc.buf, *open = bo.buf, *ins = bi.buf;
        double *bary = bb.buf;
        const int64_t faces = f3 / 3;
        for (Py_ssize_t i = 0; i < n; ++i)
            if (T[i] < 0 || T[i] >= faces) {
                PyErr_SetString(PyExc_IndexError, "triangle index out of range");
                goto done;
            }
        for (Py_ssize_t i = 0; i < f3; ++i)
            if (COR[i] < 0 || COR[i] > 2) {
                PyErr_SetString(PyExc_ValueError, "corner must be a permutation of 0, 1, 2");
                goto done;
            }
        const double margin = 1.0 + 1e-9;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n; ++i) {
            const int64_t tri = T[i];
            const double *ax = AX + 3 * tri, *ay = AY + 3 * tri, *dx = DX + 3 * tri, *dy = DY + 3 * tri;
            const uint8_t *own = OWN + 3 * tri;
            const int64_t *cor = COR + 3 * tri;
            const double fx = (double)COL[i], fy = (double)ROW[i];
            const double cx = fx + 0.5, cy = fy + 0.5;
            double ec[3];
            int touch = 1, opened = 1;
            for (int e = 0; e < 3; ++e) {
                ec[e] = edge_value(ax, ay, dx, dy, e, cx, cy);
                const double half = 0.5 * (fabs(dx[e]) + fabs(dy[e]));
                touch &= ec[e] + half * margin >= 0;
                opened &= ec[e] + half > 0;
            }
            opened &= (VM[2 * tri] > fx) & (VM[2 * tri + 1] > fy);
            centre[i] = (uint8_t)on_triangle(ec, own);
            open[i] = (uint8_t)opened;
            const uint64_t texel = (uint64_t)(ROW[i] * (int64_t)width + COL[i]);
            for (Py_ssize_t k = 0; k < n_sub; ++k) {
                double e[3];
                int landed;
                if (n_sub == 1) {
                    e[0] = ec[0], e[1] = ec[1], e[2] = ec[2];
                    landed = centre[i];
                } else if (!touch) {
                    landed = 0;
                } else {
                    const double ux = jitter(seed_key, texel, (uint64_t)k, 0);
                    const double uy = jitter(seed_key, texel, (uint64_t)k, 1);
                    double ox, oy;
                    if (q * q == n_sub) {
                        ox = ((double)(k % q) + ux) / (double)q;
                        oy = ((double)(k / q) + uy) / (double)q;
                    } else {
                        ox = ((double)k + ux) / (double)n_sub;
                        oy = ((double)((k * g) % n_sub) + uy) / (double)n_sub;
                    }
                    const double x = fx + ox, y = fy + oy;
                    for (int j = 0; j < 3; ++j)
                        e[j] = edge_value(ax, ay, dx, dy, j, x, y);
                    landed = on_triangle(e, own);
                }
                ins[k * n + i] = (uint8_t)landed;
                double *out = bary + 3 * (k * n + i);
                if (landed) {
                    /* Edge j is opposite oriented vertex j + 2: weights (E1, E2, E0). */
                    const double w[3] = {e[1], e[2], e[0]};
                    const double sum = (w[0] + w[1]) + w[2];
                    for (int j = 0; j < 3; ++j)
                        out[cor[j]] = w[j] / sum;
                } else {
                    out[0] = out[1] = out[2] = 0.0;
                }
            }
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&bax); PyBuffer_Release(&bay); PyBuffer_Release(&bdx); PyBuffer_Release(&bdy);
    PyBuffer_Release(&bown); PyBuffer_Release(&bcor); PyBuffer_Release(&bvm); PyBuffer_Release(&bt);
    PyBuffer_Release(&brow); PyBuffer_Release(&bcol); PyBuffer_Release(&bc); PyBuffer_Release(&bo);
    PyBuffer_Release(&bi); PyBuffer_Release(&bb);
    return result;
}

/* The seam system's operator (W + P^T S P) x of aobake.targets.texels.seams._apply, in its
 * order of operations: u = P x (fill); per group of seam points, its eight texels' sums
 * over the group's points p, in order, of (lam_p d_p) g_p with d_p = g_p . u (a fixed
 * pairwise tree of the eight products), scattered in group order; out = w x + P^T v.  The points'
 * weights (m, 8) are read, not 8 x 8 group matrices: half the bytes per iteration, and
 * the solve is bound by memory. */
typedef struct {
    Py_ssize_t n, groups, fills;
    const double *coef, *lam, *w, *fill_weight;
    const int64_t *starts, *slots, *fill_to, *fill_from;
    const uint8_t *gutter;
} SeamOp;

static void seam_apply(const SeamOp *op, const double *x, double *u, double *v, double *out)
{
    const Py_ssize_t n = op->n;
    for (Py_ssize_t i = 0; i < n; ++i)
        v[i] = 0.0;
    for (Py_ssize_t e = 0; e < op->fills; ++e)
        v[op->fill_to[e]] += op->fill_weight[e] * x[op->fill_from[e]];
    for (Py_ssize_t i = 0; i < n; ++i)
        u[i] = (op->gutter[i] ? 0.0 : x[i]) + v[i];
    for (Py_ssize_t i = 0; i < n; ++i)
        v[i] = 0.0;
    for (Py_ssize_t g = 0; g < op->groups; ++g) {
        const int64_t *s = op->slots + 8 * g;
        double ug[8], acc[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
        for (int l = 0; l < 8; ++l)
            ug[l] = u[s[l]];
        for (int64_t p = op->starts[g]; p < op->starts[g + 1]; ++p) {
            const double *c = op->coef + 8 * p;
            /* a fixed pairwise tree: three additions deep, not seven */
            const double d = ((c[0] * ug[0] + c[1] * ug[1]) + (c[2] * ug[2] + c[3] * ug[3]))
                             + ((c[4] * ug[4] + c[5] * ug[5]) + (c[6] * ug[6] + c[7] * ug[7]));
            const double t = op->lam[p] * d;
            for (int k = 0; k < 8; ++k)
                acc[k] += t * c[k];
        }
        for (int k = 0; k < 8; ++k)
            v[s[k]] += acc[k];
    }
    /* P^T v: u is free again and holds the fill's share of each covered texel */
    for (Py_ssize_t i = 0; i < n; ++i)
        u[i] = 0.0;
    for (Py_ssize_t e = 0; e < op->fills; ++e)
        u[op->fill_from[e]] += op->fill_weight[e] * v[op->fill_to[e]];
    for (Py_ssize_t i = 0; i < n; ++i)
        out[i] = op->w[i] * x[i] + ((op->gutter[i] ? 0.0 : v[i]) + u[i]);
}

/* a . b summed in index order from the first product (numpy's cumsum of the reference) */
static double seq_dot(const double *a, const double *b, Py_ssize_t n)
{
    if (n == 0)
        return 0.0;
    double acc = a[0] * b[0];
    for (Py_ssize_t i = 1; i < n; ++i)
        acc += a[i] * b[i];
    return acc;
}

static double max_abs(const double *a, Py_ssize_t n)
{
    double m = 0.0;
    for (Py_ssize_t i = 0; i < n; ++i)
        if (fabs(a[i]) > m)
            m = fabs(a[i]);
    return m;
}

/* seam_cg(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w, diag, b, x,
 *         tolerance, max_iterations) -> (iterations, the last max |r / diag|)
 *
 * Jacobi-preconditioned conjugate gradients on (W + P^T S P) x = W b from x = b, stopping
 * when max |r / diag| <= tolerance or after max_iterations: aobake.targets.texels.seams.
 * _cg_numpy operation for operation (tested bit for bit).  coef (m, 8), lam (m,) float64
 * the seam points' weights, starts (G + 1,) int64 (group g is points starts[g] ..
 * starts[g + 1] - 1), slots (G, 8) int64 in 0..n-1, gutter (n,) bool, fill_* (e,)
 * (fill_to, fill_from int64 in 0..n-1), w, diag, b (n,) float64; x (n,) float64 written.
 */
static PyObject *seam_cg(PyObject *self, PyObject *args)
{
    Py_buffer bcoef = {0}, blam = {0}, bstarts = {0};
    Py_buffer bslots = {0}, bgut = {0}, bto = {0}, bfrom = {0}, bfw = {0};
    Py_buffer bw = {0}, bdiag = {0}, bb = {0}, bx = {0};
    double tolerance;
    Py_ssize_t max_iterations, it = 0;
    double left = 0.0;
    double *scratch = NULL;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*w*dn", &bcoef, &blam, &bstarts, &bslots,
                          &bgut, &bto, &bfrom, &bfw, &bw, &bdiag, &bb, &bx, &tolerance,
                          &max_iterations))
        return NULL;
    {
        const Py_ssize_t n = bgut.len, groups = bslots.len / 64, fills = bto.len / 8;
        const Py_ssize_t m = blam.len / 8;
        if (check(&bcoef, "coef", 8, 8 * m) || check(&blam, "lam", 8, m) ||
            check(&bstarts, "starts", 8, groups + 1) || check(&bslots, "slots", 8, 8 * groups) ||
            check(&bgut, "gutter", 1, n) || check(&bto, "fill_to", 8, fills) ||
            check(&bfrom, "fill_from", 8, fills) || check(&bfw, "fill_weight", 8, fills) ||
            check(&bw, "w", 8, n) || check(&bdiag, "diag", 8, n) || check(&bb, "b", 8, n) ||
            check(&bx, "x", 8, n))
            goto done;
        const int64_t *starts = bstarts.buf;
        if (starts[0] != 0 || starts[groups] != m) {
            PyErr_SetString(PyExc_ValueError, "starts must run from 0 to m");
            goto done;
        }
        for (Py_ssize_t g = 0; g < groups; ++g)
            if (starts[g] > starts[g + 1]) {
                PyErr_SetString(PyExc_ValueError, "starts must be non-decreasing");
                goto done;
            }
        const int64_t *slots = bslots.buf, *to = bto.buf, *from = bfrom.buf;
        for (Py_ssize_t i = 0; i < 8 * groups; ++i)
            if (slots[i] < 0 || slots[i] >= n) {
                PyErr_SetString(PyExc_IndexError, "slot out of range");
                goto done;
            }
        for (Py_ssize_t e = 0; e < fills; ++e)
            if (to[e] < 0 || to[e] >= n || from[e] < 0 || from[e] >= n) {
                PyErr_SetString(PyExc_IndexError, "fill index out of range");
                goto done;
            }
        scratch = PyMem_RawMalloc(sizeof(double) * (size_t)(6 * n + 1));
        if (!scratch) {
            PyErr_NoMemory();
            goto done;
        }
        const SeamOp op = {n, groups, fills, bcoef.buf, blam.buf, bw.buf, bfw.buf, starts, slots, to,
                           from, bgut.buf};
        const double *w = bw.buf, *diag = bdiag.buf, *b = bb.buf;
        double *x = bx.buf;
        double *r = scratch, *z = r + n, *p = z + n, *q = p + n, *u = q + n, *v = u + n;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n; ++i)
            x[i] = b[i];
        seam_apply(&op, x, u, v, q);
        for (Py_ssize_t i = 0; i < n; ++i) {
            r[i] = w[i] * b[i] - q[i];
            z[i] = r[i] / diag[i];
            p[i] = z[i];
        }
        double rz = seq_dot(r, z, n);
        while (max_abs(z, n) > tolerance && it < max_iterations) {
            seam_apply(&op, p, u, v, q);
            const double alpha = rz / seq_dot(p, q, n);
            for (Py_ssize_t i = 0; i < n; ++i) {
                x[i] += alpha * p[i];
                r[i] -= alpha * q[i];
                z[i] = r[i] / diag[i];
            }
            const double rz_old = rz;
            rz = seq_dot(r, z, n);
            const double beta = rz / rz_old;
            for (Py_ssize_t i = 0; i < n; ++i)
                p[i] = z[i] + beta * p[i];
            ++it;
        }
        left = max_abs(z, n);
        Py_END_ALLOW_THREADS
    }
    result = Py_BuildValue("nd", it, left);

done:
    PyMem_RawFree(scratch);
    PyBuffer_Release(&bcoef); PyBuffer_Release(&blam); PyBuffer_Release(&bstarts);
    PyBuffer_Release(&bslots); PyBuffer_Release(&bgut);
    PyBuffer_Release(&bto); PyBuffer_Release(&bfrom); PyBuffer_Release(&bfw);
    PyBuffer_Release(&bw); PyBuffer_Release(&bdiag); PyBuffer_Release(&bb); PyBuffer_Release(&bx);
    return result;
}

/* radix_argsort(keys, bits, out_order, out_sorted)
 *
 * The stable argsort of keys (n,) uint32 below 2^bits (aobake.rng.stable_argsort: a stable
 * sort's permutation is unique, so the result is that of numpy's): a least-significant-digit
 * radix sort, 11 bits a pass.  out_order (n,) int64 the permutation, out_sorted (n,) uint32
 * keys[out_order], both written.
 */
#define RADIX_BITS 11
static PyObject *radix_argsort(PyObject *self, PyObject *args)
{
    Py_buffer bk = {0}, bo = {0}, bs = {0};
    Py_ssize_t bits;
    uint32_t *tmp_key = NULL;
    int64_t *tmp_idx = NULL;
    Py_ssize_t *count = NULL;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*nw*w*", &bk, &bits, &bo, &bs))
        return NULL;
    {
        const Py_ssize_t n = bk.len / 4;
        if (bits < 0 || bits > 32) {
            PyErr_SetString(PyExc_ValueError, "bits must be in 0..32");
            goto done;
        }
        if (check(&bk, "keys", 4, n) || check(&bo, "out_order", 8, n) ||
            check(&bs, "out_sorted", 4, n))
            goto done;
        const uint32_t *keys = bk.buf;
        int64_t *order = bo.buf;
        uint32_t *sorted = bs.buf;
        const int passes = (int)((bits + RADIX_BITS - 1) / RADIX_BITS);
        if (bits < 32)
            for (Py_ssize_t i = 0; i < n; ++i)
                if (keys[i] >> bits) {
                    PyErr_SetString(PyExc_ValueError, "a key is not below 2^bits");
                    goto done;
                }
        tmp_key = PyMem_RawMalloc(sizeof(uint32_t) * (size_t)(n + 1));
        tmp_idx = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(n + 1));
        count = PyMem_RawMalloc(sizeof(Py_ssize_t) << RADIX_BITS);
        if (!tmp_key || !tmp_idx || !count) {
            PyErr_NoMemory();
            goto done;
        }
        Py_BEGIN_ALLOW_THREADS
        /* the pass that ends in the output buffers starts from the other pair */
        uint32_t *src_key = (passes % 2) ? tmp_key : sorted, *dst_key;
        int64_t *src_idx = (passes % 2) ? tmp_idx : order, *dst_idx;
        for (Py_ssize_t i = 0; i < n; ++i) {
            src_key[i] = keys[i];
            src_idx[i] = i;
        }
        for (int p = 0; p < passes; ++p) {
            const int shift = p * RADIX_BITS;
            const uint32_t mask = (1u << RADIX_BITS) - 1u;
            dst_key = src_key == sorted ? tmp_key : sorted;
            dst_idx = src_idx == order ? tmp_idx : order;
            for (int d = 0; d <= (int)mask; ++d)
                count[d] = 0;
            for (Py_ssize_t i = 0; i < n; ++i)
                ++count[(src_key[i] >> shift) & mask];
            Py_ssize_t at = 0;
            for (int d = 0; d <= (int)mask; ++d) {
                const Py_ssize_t c = count[d];
                count[d] = at;
                at += c;
            }
            for (Py_ssize_t i = 0; i < n; ++i) {  /* in input order: stable */
                const Py_ssize_t to = count[(src_key[i] >> shift) & mask]++;
                dst_key[to] = src_key[i];
                dst_idx[to] = src_idx[i];
            }
            src_key = dst_key;
            src_idx = dst_idx;
        }
        Py_END_ALLOW_THREADS
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyMem_RawFree(tmp_key);
    PyMem_RawFree(tmp_idx);
    PyMem_RawFree(count);
    PyBuffer_Release(&bk); PyBuffer_Release(&bo); PyBuffer_Release(&bs);
    return result;
}

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
static PyObject *surface_interp(PyObject *self, PyObject *args)
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

/* The atlas packer's kernels, in _pack.c. */
PyObject *chart_marks(PyObject *self, PyObject *args);
PyObject *pack_charts(PyObject *self, PyObject *args);

static PyMethodDef methods[] = {
    {"fill_rays", fill_rays, METH_VARARGS,
     "fill_rays(origins, normals, keys, table, sampler, weighting, nx, ny, k, R, m, js, mp, "
     "out_origins, out_directions): write point-major ray origins and directions."},
    {"raster_pairs", raster_pairs, METH_VARARGS,
     "raster_pairs(ax, ay, dx, dy, owner, corner, vmax, t, row, col, width, n_sub, seed_key, q, g, "
     "out_centre, out_open, out_ins, out_bary): per-pair rasteriser tests."},
    {"row_counts", row_counts, METH_VARARGS,
     "row_counts(flags, rows, m, out): nonzero flags per row of m."},
    {"radix_argsort", radix_argsort, METH_VARARGS,
     "radix_argsort(keys, bits, out_order, out_sorted): stable argsort of uint32 keys."},
    {"surface_interp", surface_interp, METH_VARARGS,
     "surface_interp(positions, normals, faces, face, bary, out_points, out_normals, out_length): "
     "lightmap sample points and unit shading normals."},
    {"seam_cg", seam_cg, METH_VARARGS,
     "seam_cg(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w, diag, b, x, "
     "tolerance, "
     "max_iterations) -> (iterations, max |r / diag|): the seam erasure's Jacobi-preconditioned CG."},
    {"chart_marks", chart_marks, METH_VARARGS,
     "chart_marks(xy, faces, face_chart, mask_offset, size, padding, out_covered, out_padded): "
     "the atlas packer's chart masks (unwrap._chart_masks)."},
    {"pack_charts", pack_charts, METH_VARARGS,
     "pack_charts(masks, offsets, shapes, order, width, height, upright, hole_cap, hole_run, "
     "hole_rows, max_searches, out_place[, state]) -> (fits, placed, used): "
     "unwrap._pack_in_order."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "aobake._kernels",
    "Compiled per-ray kernels of aobake (see aobake.rays).", -1, methods,
};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
