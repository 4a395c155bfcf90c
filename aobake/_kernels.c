/* aobake._kernels: the per-ray part of ray generation, the AO escape counts,
 * the lightmap rasteriser and the seam erasure's solve, compiled.
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
#include "_buffers.h"
#include <math.h>
#include <stdint.h>


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

/* The rasteriser's tests (aobake.targets.texels.raster._raster_chunk, operation for
 * operation): oriented edge functions E = dx (y - ay) - dy (x - ax), the coverage rule
 * and the sub-position jitter. */
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

/* raster_rows(ax, ay, dx, dy, owner, corner, vmax, verts, c0, c1, row_start, row_tris, width,
 *             n_sub, seed_key, q, g, row_lo, row_hi, write, rows,
 *             out_texel, out_face, out_bary, out_sample, out_fallback, coverage, shared)
 *
 * The whole rasteriser of aobake.targets.texels.raster for the image rows row_lo ..
 * row_hi - 1, emitting its samples already in their final order, so that no per-pair
 * temporaries, concatenations, global sort or fallback insertion are needed (on the
 * bunny at 1024^2 those cost ~0.8 s, mostly first touches of fresh memory, against
 * 0.24 s of tests).  The tests are _raster_chunk's, operation for operation; the fallback
 * sample is _nearest_on_triangle's.
 *
 * A row's triangles (row_tris[row_start[r] .. row_start[r + 1] - 1], ascending) are
 * tested texel by texel of their clipped column range c0 .. c1; the landed
 * sub-positions of the row are then ordered by (column, sub-position), ties in triangle
 * order: the order the reference's stable sort of (texel, sub-position) gives.  A texel
 * where nothing landed but a triangle overlaps its open square gets one fallback
 * sample: the nearest point of the overlapping triangles to its centre (smallest
 * distance, then lowest triangle; a NaN distance last, as np.lexsort).
 *
 * write = 0: rows[r] = the number of samples of row r (fallbacks included).
 * write = 1: rows[r] = the first output index of row r; the samples are written to
 * out_texel, out_face, out_sample (int64), out_bary (3 float64), out_fallback (bool),
 * and each texel's coverage (float32: distinct landed sub-positions / K, or 0.5 / K for
 * a fallback) and shared (int32: triangles covering its centre).
 * verts (f, 3, 2) float64 the oriented vertices; c0, c1 (f,) int64 clipped to the image.
 */
typedef struct {
    int64_t col, k, tri;
    double b[3];
} RasterEntry;

static inline double clip01(double s) /* np.clip(s, 0, 1): keeps NaN and -0.0 */
{
    s = s < 0.0 ? 0.0 : s;
    return s > 1.0 ? 1.0 : s;
}

/* _nearest_on_triangle for one point: barycentrics (face-corner order) and distance^2. */
static double nearest_on_triangle(const double *v, const double *ax, const double *ay,
                                  const double *dx, const double *dy, const int64_t *cor,
                                  double px, double py, double *out)
{
    double best = INFINITY, w[3] = {0.0, 0.0, 0.0};
    for (int i = 0; i < 3; ++i) {
        const int j = (i + 1) % 3;
        const double a0 = v[2 * i], a1 = v[2 * i + 1];
        const double d0 = v[2 * j] - a0, d1 = v[2 * j + 1] - a1;
        double num = 0.0, den = 0.0; /* einsum sums from 0 */
        num += (px - a0) * d0;
        num += (py - a1) * d1;
        den += d0 * d0;
        den += d1 * d1;
        const double s = clip01(num / den);
        const double e0 = a0 + s * d0 - px, e1 = a1 + s * d1 - py;
        double d2 = 0.0;
        d2 += e0 * e0;
        d2 += e1 * e1;
        if (d2 < best) {
            best = d2;
            w[0] = w[1] = w[2] = 0.0;
            w[i] = 1.0 - s;
            w[j] = s;
        }
    }
    double e[3];
    for (int j = 0; j < 3; ++j)
        e[j] = edge_value(ax, ay, dx, dy, j, px, py);
    if (e[0] >= 0 && e[1] >= 0 && e[2] >= 0) {
        const double wi[3] = {e[1], e[2], e[0]};
        const double sum = (wi[0] + wi[1]) + wi[2];
        for (int j = 0; j < 3; ++j)
            w[j] = wi[j] / sum;
        best = 0.0;
    }
    for (int j = 0; j < 3; ++j)
        out[cor[j]] = w[j];
    return best;
}

/* a before b in np.lexsort((face, d2)) order: d2 ascending (NaN last), then face */
static inline int nearer(double da, int64_t fa, double db, int64_t fb)
{
    if (isnan(da) || isnan(db))
        return isnan(db) && (!isnan(da) || fa < fb);
    return da < db || (da == db && fa < fb);
}

static PyObject *raster_rows(PyObject *self, PyObject *args)
{
    Py_buffer bax = {0}, bay = {0}, bdx = {0}, bdy = {0}, bown = {0}, bcor = {0}, bvm = {0};
    Py_buffer bv = {0}, bc0 = {0}, bc1 = {0}, brs = {0}, brt = {0}, brows = {0};
    Py_buffer bot = {0}, bof = {0}, bob = {0}, bos = {0}, bofb = {0}, bcov = {0}, bsh = {0};
    Py_ssize_t width, n_sub, q, g, row_lo, row_hi;
    int write;
    unsigned long long seed_key;
    PyObject *result = NULL;
    char *scratch = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*y*nnKnnnnpw*w*w*w*w*w*w*w*", &bax, &bay,
                          &bdx, &bdy, &bown, &bcor, &bvm, &bv, &bc0, &bc1, &brs, &brt, &width,
                          &n_sub, &seed_key, &q, &g, &row_lo, &row_hi, &write, &brows, &bot,
                          &bof, &bob, &bos, &bofb, &bcov, &bsh))
        return NULL;
    {
        const Py_ssize_t f3 = bax.len / 8, faces = f3 / 3, height = brows.len / 8;
        const Py_ssize_t n_out = bof.len / 8, n_pix = width * height;
        if (n_sub < 1 || q < 1 || g < 0 || width < 1 || f3 % 3 || row_lo < 0 ||
            row_hi < row_lo || row_hi > height) {
            PyErr_SetString(PyExc_ValueError, "bad sizes");
            goto done;
        }
        if (check(&bax, "ax", 8, f3) || check(&bay, "ay", 8, f3) || check(&bdx, "dx", 8, f3) ||
            check(&bdy, "dy", 8, f3) || check(&bown, "owner", 1, f3) ||
            check(&bcor, "corner", 8, f3) || check(&bvm, "vmax", 8, 2 * faces) ||
            check(&bv, "verts", 8, 6 * faces) || check(&bc0, "c0", 8, faces) ||
            check(&bc1, "c1", 8, faces) || check(&brs, "row_start", 8, height + 1) ||
            check(&brt, "row_tris", 8, brt.len / 8) || check(&brows, "rows", 8, height) ||
            check(&bot, "out_texel", 8, n_out) || check(&bof, "out_face", 8, n_out) ||
            check(&bob, "out_bary", 8, 3 * n_out) || check(&bos, "out_sample", 8, n_out) ||
            check(&bofb, "out_fallback", 1, n_out) ||
            (write && (check(&bcov, "coverage", 4, n_pix) || check(&bsh, "shared", 4, n_pix))))
            goto done;
        const double *AX = bax.buf, *AY = bay.buf, *DX = bdx.buf, *DY = bdy.buf, *VM = bvm.buf;
        const double *V = bv.buf;
        const uint8_t *OWN = bown.buf;
        const int64_t *COR = bcor.buf, *C0 = bc0.buf, *C1 = bc1.buf, *RS = brs.buf, *RT = brt.buf;
        const Py_ssize_t n_tris = brt.len / 8;
        int64_t *rows = brows.buf, *otex = bot.buf, *oface = bof.buf, *osub = bos.buf;
        double *obary = bob.buf;
        uint8_t *ofb = bofb.buf;
        float *cov = bcov.buf;
        int32_t *shared = bsh.buf;
        if (RS[0] != 0 || RS[height] != n_tris) {
            PyErr_SetString(PyExc_ValueError, "row_start must run from 0 to len(row_tris)");
            goto done;
        }
        Py_ssize_t most = 1; /* the most (pair, sub-position) entries of one row */
        for (Py_ssize_t r = row_lo; r < row_hi; ++r) {
            if (RS[r] > RS[r + 1]) {
                PyErr_SetString(PyExc_ValueError, "row_start must be non-decreasing");
                goto done;
            }
            Py_ssize_t pairs = 0;
            for (int64_t i = RS[r]; i < RS[r + 1]; ++i) {
                const int64_t t = RT[i];
                if (t < 0 || t >= faces || C0[t] < 0 || C1[t] >= width) {
                    PyErr_SetString(PyExc_IndexError, "triangle or column out of range");
                    goto done;
                }
                if (C1[t] >= C0[t])
                    pairs += C1[t] - C0[t] + 1;
            }
            if (pairs * n_sub > most)
                most = pairs * n_sub;
        }
        for (Py_ssize_t i = 0; i < f3; ++i)
            if (COR[i] < 0 || COR[i] > 2) {
                PyErr_SetString(PyExc_ValueError, "corner must be a permutation of 0, 1, 2");
                goto done;
            }
        /* scratch: entries and their sorted copy; per column: counts, landed flags (K),
         * and the best fallback candidate */
        const size_t W = (size_t)width, K = (size_t)n_sub;
        const size_t entries = write ? (size_t)most : 0; /* counting stores none */
        const size_t bytes = 2 * entries * sizeof(RasterEntry) + (W + 1) * 8 + W * K +
                             W * (8 + 8 + 24 + 1) + 64;
        scratch = PyMem_RawCalloc(1, bytes);
        if (!scratch) {
            PyErr_NoMemory();
            goto done;
        }
        RasterEntry *entry = (RasterEntry *)scratch, *sorted = entry + entries;
        int64_t *count = (int64_t *)(sorted + entries);
        double *best_d2 = (double *)(count + W + 1);
        int64_t *best_face = (int64_t *)(best_d2 + W);
        double *best_bary = (double *)(best_face + W);
        uint8_t *landed = (uint8_t *)(best_bary + 3 * W), *has_cand = landed + W * K;
        const double margin = 1.0 + 1e-9;
        const float fallback_coverage = (float)(0.5 / (double)n_sub);
        int overflow = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t r = row_lo; r < row_hi && !overflow; ++r) {
            int64_t lo = width, hi = -1;
            Py_ssize_t m = 0;
            const double fy = (double)r, cy = fy + 0.5;
            for (int64_t i = RS[r]; i < RS[r + 1]; ++i) {
                const int64_t tri = RT[i];
                const double *ax = AX + 3 * tri, *ay = AY + 3 * tri, *dx = DX + 3 * tri,
                             *dy = DY + 3 * tri;
                const uint8_t *own = OWN + 3 * tri;
                const int64_t *cor = COR + 3 * tri;
                if (C0[tri] < lo)
                    lo = C0[tri];
                if (C1[tri] > hi)
                    hi = C1[tri];
                for (int64_t col = C0[tri]; col <= C1[tri]; ++col) {
                    const double fx = (double)col, cx = fx + 0.5;
                    double ec[3];
                    int touch = 1, opened = 1;
                    for (int e = 0; e < 3; ++e) {
                        ec[e] = edge_value(ax, ay, dx, dy, e, cx, cy);
                        const double half = 0.5 * (fabs(dx[e]) + fabs(dy[e]));
                        touch &= ec[e] + half * margin >= 0;
                        opened &= ec[e] + half > 0;
                    }
                    opened &= (VM[2 * tri] > fx) & (VM[2 * tri + 1] > fy);
                    const int centre = on_triangle(ec, own);
                    if (write && centre)
                        shared[r * width + col] += 1;
                    const uint64_t texel = (uint64_t)(r * (int64_t)width + col);
                    int hit = 0;
                    for (Py_ssize_t k = 0; k < n_sub; ++k) {
                        double e[3];
                        int in;
                        if (n_sub == 1) {
                            e[0] = ec[0], e[1] = ec[1], e[2] = ec[2];
                            in = centre;
                        } else if (!touch) {
                            in = 0;
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
                            in = on_triangle(e, own);
                        }
                        if (!in)
                            continue;
                        hit = 1;
                        landed[col * K + k] = 1;
                        if (write) { /* counting needs only m and the flags */
                            RasterEntry *en = entry + m;
                            en->col = col, en->k = k, en->tri = tri;
                            /* Edge j is opposite oriented vertex j + 2: weights (E1, E2, E0). */
                            const double w[3] = {e[1], e[2], e[0]};
                            const double sum = (w[0] + w[1]) + w[2];
                            for (int j = 0; j < 3; ++j)
                                en->b[cor[j]] = w[j] / sum;
                        }
                        ++m;
                    }
                    if (opened && !hit) { /* a fallback candidate */
                        if (!write) {
                            has_cand[col] = 1;
                            continue;
                        }
                        double b[3];
                        const double d2 = nearest_on_triangle(V + 6 * tri, ax, ay, dx, dy, cor,
                                                              cx, cy, b);
                        if (!has_cand[col] || nearer(d2, tri, best_d2[col], best_face[col])) {
                            best_d2[col] = d2, best_face[col] = tri;
                            best_bary[3 * col] = b[0], best_bary[3 * col + 1] = b[1];
                            best_bary[3 * col + 2] = b[2];
                        }
                        has_cand[col] = 1;
                    }
                }
            }
            Py_ssize_t total = 0;
            if (!write && hi >= lo) { /* the row's samples: landed ones + one per fallback */
                total = m;
                for (int64_t c = lo; c <= hi; ++c) {
                    int any = 0;
                    for (size_t k = 0; k < K; ++k) {
                        any |= landed[c * K + k];
                        landed[c * K + k] = 0;
                    }
                    total += has_cand[c] && !any;
                    has_cand[c] = 0;
                }
            } else if (hi >= lo) { /* stable counting sort of the row's entries by column ... */
                for (int64_t c = lo; c <= hi + 1; ++c)
                    count[c - lo] = 0;
                for (Py_ssize_t i = 0; i < m; ++i)
                    count[entry[i].col - lo + 1] += 1;
                for (int64_t c = lo; c <= hi; ++c)
                    count[c - lo + 1] += count[c - lo];
                for (Py_ssize_t i = 0; i < m; ++i)
                    sorted[count[entry[i].col - lo]++] = entry[i];
                /* count[c - lo] is now the end of column c's run */
                Py_ssize_t start = 0;
                for (int64_t c = lo; c <= hi; ++c) {
                    const Py_ssize_t end = count[c - lo];
                    /* ... then by sub-position within the column, stably (insertion) */
                    for (Py_ssize_t i = start + 1; i < end; ++i) {
                        const RasterEntry key = sorted[i];
                        Py_ssize_t j = i;
                        while (j > start && sorted[j - 1].k > key.k) {
                            sorted[j] = sorted[j - 1];
                            --j;
                        }
                        sorted[j] = key;
                    }
                    int distinct = 0;
                    for (size_t k = 0; k < K; ++k)
                        distinct += landed[c * K + k];
                    const int fallback = end == start && has_cand[c];
                    const Py_ssize_t n_here = (end - start) + fallback;
                    if (write) {
                        const int64_t texel = r * (int64_t)width + c;
                        Py_ssize_t at = rows[r] + total;
                        if (at + n_here > n_out) {
                            overflow = 1;
                            break;
                        }
                        for (Py_ssize_t i = start; i < end; ++i, ++at) {
                            otex[at] = texel, oface[at] = sorted[i].tri, osub[at] = sorted[i].k;
                            ofb[at] = 0;
                            for (int j = 0; j < 3; ++j)
                                obary[3 * at + j] = sorted[i].b[j];
                        }
                        if (fallback) {
                            otex[at] = texel, oface[at] = best_face[c], osub[at] = 0, ofb[at] = 1;
                            for (int j = 0; j < 3; ++j)
                                obary[3 * at + j] = best_bary[3 * c + j];
                            cov[texel] = fallback_coverage;
                        } else if (distinct) {
                            cov[texel] = (float)distinct / (float)n_sub;
                        }
                    }
                    total += n_here;
                    for (size_t k = 0; k < K; ++k)
                        landed[c * K + k] = 0;
                    has_cand[c] = 0;
                    start = end;
                }
            }
            if (!write)
                rows[r] = total;
        }
        Py_END_ALLOW_THREADS
        if (overflow) {
            PyErr_SetString(PyExc_IndexError, "raster_rows: outputs too small for the rows");
            goto done;
        }
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyMem_RawFree(scratch);
    PyBuffer_Release(&bax); PyBuffer_Release(&bay); PyBuffer_Release(&bdx); PyBuffer_Release(&bdy);
    PyBuffer_Release(&bown); PyBuffer_Release(&bcor); PyBuffer_Release(&bvm); PyBuffer_Release(&bv);
    PyBuffer_Release(&bc0); PyBuffer_Release(&bc1); PyBuffer_Release(&brs); PyBuffer_Release(&brt);
    PyBuffer_Release(&brows); PyBuffer_Release(&bot); PyBuffer_Release(&bof);
    PyBuffer_Release(&bob); PyBuffer_Release(&bos); PyBuffer_Release(&bofb);
    PyBuffer_Release(&bcov); PyBuffer_Release(&bsh);
    return result;
}

/* The seam erasure's normal matrix A = W + P^T S P over the covered unknowns, assembled
 * once (seam_pattern, then seam_values), and the conjugate gradients on it (seam_csr_cg):
 * each iteration is
 * then one pass over a CSR matrix, where the operator applied as the points (the fill,
 * the group sums, their scatter, the fill's transpose: four passes of random reads) took
 * three times as long (the bunny's 114k unknowns: ~10 -> ~3 ms an iteration).
 *
 * aobake.targets.texels.seams._assemble_numpy and _cg_numpy are the reference, operation
 * for operation (tested bit for bit):
 *   block[g][k][l] = sum over the group's points p, in order, of (lam_p c_pk) c_pl;
 *   a slot's texel t maps to the unknowns map(t): itself (weight 1) when covered, else
 *   its fill entries (fill_from, fill_weight, in entry order);
 *   A_ab = the sum, from 0.0 in the order of generation (g, k, a's entry, l, b's entry),
 *   of (block[g][k][l] w_a) w_b, then + 0.0 (every diagonal is stored), then the
 *   diagonal's + w_a. */

/* A barrier for the solve's threads (pthread_barrier_t is not on every platform). */
#ifndef _WIN32
#include <pthread.h>
typedef struct {
    pthread_mutex_t lock;
    pthread_cond_t turn;
    int count, waiting;
    unsigned generation;  /* wraps harmlessly: only equality is tested */
    int gate;  /* 0: the started threads wait; 1: go; -1: give up (a thread failed to start) */
} Barrier;

/* A started thread's first step: wait until all are started; 0 if they could not be. */
static int barrier_gate(Barrier *b)
{
    pthread_mutex_lock(&b->lock);
    while (b->gate == 0)
        pthread_cond_wait(&b->turn, &b->lock);
    const int go = b->gate > 0;
    pthread_mutex_unlock(&b->lock);
    return go;
}

static void barrier_open(Barrier *b, int gate)
{
    pthread_mutex_lock(&b->lock);
    b->gate = gate;
    pthread_cond_broadcast(&b->turn);
    pthread_mutex_unlock(&b->lock);
}

static void barrier_wait(Barrier *b)
{
    if (b->count <= 1)
        return;
    pthread_mutex_lock(&b->lock);
    const unsigned generation = b->generation;
    if (++b->waiting == b->count) {
        b->waiting = 0;
        ++b->generation;
        pthread_cond_broadcast(&b->turn);
    } else {
        while (generation == b->generation)
            pthread_cond_wait(&b->turn, &b->lock);
    }
    pthread_mutex_unlock(&b->lock);
}
#else
typedef struct { int count; } Barrier;
static void barrier_wait(Barrier *b) { (void)b; }
#endif

/* ptr (n + 1,) and list (len,): for each target i, the entries e with target[e] == i in
 * ascending e (a counting sort; ptr must be zeroed).  target[e] in 0..n-1. */
static void gather_lists(const int64_t *target, Py_ssize_t len, Py_ssize_t n, int64_t *ptr,
                         int64_t *list)
{
    for (Py_ssize_t e = 0; e < len; ++e)
        ++ptr[target[e] + 1];
    for (Py_ssize_t i = 0; i < n; ++i)
        ptr[i + 1] += ptr[i];
    for (Py_ssize_t e = 0; e < len; ++e)
        list[ptr[target[e]]++] = e;
    for (Py_ssize_t i = n; i > 0; --i)  /* ptr[i] ran to the end of list i: shift back */
        ptr[i] = ptr[i - 1];
    ptr[0] = 0;
}

/* The unknowns' maps of seam_pattern and seam_values: slot j's texel t maps to its unknown
 * (weight 1) when covered, else to its fill entries to_list[to_ptr[t] ..] (fill_from's
 * unknowns, fill_weight). */
typedef struct {
    const int64_t *slots, *from, *cidx, *to_ptr, *to_list;
    const uint8_t *gutter;
    const double *fw;
} Maps;

/* Row a's columns, in order of first touch, into cols (mark[b] == a once touched); the
 * diagonal always among them.  Returns their count. */
static Py_ssize_t row_columns(const Maps *M, const int64_t *in_ptr, const int64_t *in_j,
                              Py_ssize_t a, int32_t *mark, int32_t *cols)
{
    Py_ssize_t count = 0;
    for (int64_t q = in_ptr[a]; q < in_ptr[a + 1]; ++q) {
        const int64_t *s = M->slots + 8 * (in_j[q] / 8);
        for (int l = 0; l < 8; ++l) {
            const int64_t t = s[l];
            if (!M->gutter[t]) {
                const int64_t b = M->cidx[t];
                if (mark[b] != (int32_t)a) {
                    mark[b] = (int32_t)a;
                    cols[count++] = (int32_t)b;
                }
                continue;
            }
            for (int64_t qq = M->to_ptr[t]; qq < M->to_ptr[t + 1]; ++qq) {
                const int64_t b = M->cidx[M->from[M->to_list[qq]]];
                if (mark[b] != (int32_t)a) {
                    mark[b] = (int32_t)a;
                    cols[count++] = (int32_t)b;
                }
            }
        }
    }
    if (mark[a] != (int32_t)a) {
        mark[a] = (int32_t)a;
        cols[count++] = (int32_t)a;
    }
    return count;
}

/* data[position of (a, b)] += term: (a, b) is in the pattern; a branch-free binary search
 * in row a's ascending columns (a branching one mispredicted at every step). */
static inline void add_at(const int64_t *indptr, const int32_t *indices, double *data,
                          int64_t a, int32_t b, double term)
{
    const int32_t *base = indices + indptr[a];
    int64_t len = indptr[a + 1] - indptr[a];
    while (len > 1) {
        const int64_t half = len / 2;
        base = base[half] <= b ? base + half : base;
        len -= half;
    }
    data[base - indices] += term;
}

#define SEAM_MAX_THREADS 16

/* One thread's rows r0 .. r1 - 1 of seam_pattern or seam_values: their pattern (pass 0: cols,
 * ascending
 * per row, counts[a] each row's count) or their values (pass 1: every group read in order,
 * only its terms of these rows added). */
typedef struct {
    const Maps *M;
    const int64_t *in_ptr, *in_j, *starts, *indptr;
    const int32_t *indices;
    const double *coef, *lam;
    double *data;
    Py_ssize_t groups, r0, r1, nnz, capacity;
    int32_t *mark, *cols, *row_cols;
    int64_t *counts;
    int pass, failed;
} AssembleWork;

static void assemble_pattern(AssembleWork *t)
{
    for (Py_ssize_t a = t->r0; a < t->r1; ++a) {
        const Py_ssize_t count = row_columns(t->M, t->in_ptr, t->in_j, a, t->mark, t->row_cols);
        int32_t *cols = t->row_cols;
        for (Py_ssize_t u = 1; u < count; ++u) {  /* a row holds a few dozen */
            const int32_t c = cols[u];
            Py_ssize_t v = u;
            for (; v > 0 && cols[v - 1] > c; --v)
                cols[v] = cols[v - 1];
            cols[v] = c;
        }
        if (t->nnz + count > t->capacity) {
            const Py_ssize_t grown = 2 * (t->nnz + count) + 1024;
            int32_t *more = PyMem_RawRealloc(t->cols, sizeof(int32_t) * (size_t)grown);
            if (!more) {
                t->failed = 1;
                return;
            }
            t->cols = more;
            t->capacity = grown;
        }
        memcpy(t->cols + t->nnz, cols, sizeof(int32_t) * (size_t)count);
        t->nnz += count;
        t->counts[a] = count;
    }
}

static void assemble_values(AssembleWork *t)
{
    const Maps *M = t->M;
    const int64_t *slots = M->slots, *to_ptr = M->to_ptr, *to_list = M->to_list;
    const int64_t *cidx = M->cidx, *from = M->from;
    const uint8_t *gutter = M->gutter;
    const double *fw = M->fw;
    for (Py_ssize_t g = 0; g < t->groups; ++g) {
        double block[64];
        for (int q = 0; q < 64; ++q)
            block[q] = 0.0;
        for (int64_t p = t->starts[g]; p < t->starts[g + 1]; ++p) {
            const double *c = t->coef + 8 * p;
            for (int k = 0; k < 8; ++k) {
                const double lk = t->lam[p] * c[k];
                for (int l = 0; l < 8; ++l)
                    block[8 * k + l] += lk * c[l];
            }
        }
        const int64_t *s = slots + 8 * g;
        for (int k = 0; k < 8; ++k) {
            const int64_t ta = s[k];
            const int64_t qa0 = gutter[ta] ? to_ptr[ta] : -1;
            const int64_t qa1 = gutter[ta] ? to_ptr[ta + 1] : 0;
            for (int64_t qa = qa0; qa < qa1; ++qa) {
                const int64_t ea = qa < 0 ? -1 : to_list[qa];
                const int64_t a = ea < 0 ? cidx[ta] : cidx[from[ea]];
                if (a < t->r0 || a >= t->r1)
                    continue;  /* another thread's row */
                const double wa = ea < 0 ? 1.0 : fw[ea];
                for (int l = 0; l < 8; ++l) {
                    const int64_t tb = s[l];
                    const double bk = block[8 * k + l] * wa;
                    if (!gutter[tb]) {
                        add_at(t->indptr, t->indices, t->data, a, (int32_t)cidx[tb], bk * 1.0);
                        continue;
                    }
                    for (int64_t qb = to_ptr[tb]; qb < to_ptr[tb + 1]; ++qb) {
                        const int64_t eb = to_list[qb];
                        add_at(t->indptr, t->indices, t->data, a, (int32_t)cidx[from[eb]],
                               bk * fw[eb]);
                    }
                }
            }
        }
    }
}

static void *assemble_thread(void *arg)
{
    AssembleWork *t = arg;
    if (t->pass == 0)
        assemble_pattern(t);
    else
        assemble_values(t);
    return NULL;
}

/* Run `threads` AssembleWork shares (on threads where they can be had: one that cannot
 * start runs on this one, after the others; the shares, not the threads, make the bits). */
static void assemble_run(AssembleWork *work, Py_ssize_t threads)
{
#ifndef _WIN32
    pthread_t handles[SEAM_MAX_THREADS];
    int started[SEAM_MAX_THREADS] = {0};
    for (Py_ssize_t k = 1; k < threads; ++k)
        started[k] = pthread_create(&handles[k], NULL, assemble_thread, &work[k]) == 0;
    assemble_thread(&work[0]);
    for (Py_ssize_t k = 1; k < threads; ++k) {
        if (started[k])
            pthread_join(handles[k], NULL);
        else
            assemble_thread(&work[k]);
    }
#else
    for (Py_ssize_t k = 0; k < threads; ++k)
        assemble_thread(&work[k]);
#endif
}

/* The arrays seam_pattern and seam_values both derive from a system: each unknown's number
 * (cidx, -1 for a gutter texel), each unknown's texel, and each gutter texel's fill entries
 * (to_ptr / to_list). */
typedef struct {
    int64_t *ints;  /* one allocation: cidx (n), texel (n), to_ptr (n + 1), to_list (fills) */
    int64_t *cidx, *texel, *to_ptr, *to_list;
    Py_ssize_t nc;
} Numbering;

/* Checks the system's index arrays and numbers its unknowns; -1 with an exception set. */
static int seam_numbering(Py_buffer *bstarts, Py_buffer *bslots, Py_buffer *bgut, Py_buffer *bto,
                          Py_buffer *bfrom, Py_ssize_t m, Numbering *out)
{
    const Py_ssize_t n = bgut->len, groups = bslots->len / 64, fills = bto->len / 8;
    if (check(bstarts, "starts", 8, groups + 1) || check(bslots, "slots", 8, 8 * groups) ||
        check(bgut, "gutter", 1, n) || check(bto, "fill_to", 8, fills) ||
        check(bfrom, "fill_from", 8, fills))
        return -1;
    const int64_t *starts = bstarts->buf, *slots = bslots->buf, *to = bto->buf, *from = bfrom->buf;
    const uint8_t *gutter = bgut->buf;
    if (starts[0] != 0 || (m >= 0 && starts[groups] != m)) {
        PyErr_SetString(PyExc_ValueError, "starts must run from 0 to m");
        return -1;
    }
    for (Py_ssize_t g = 0; g < groups; ++g)
        if (starts[g] > starts[g + 1]) {
            PyErr_SetString(PyExc_ValueError, "starts must be non-decreasing");
            return -1;
        }
    for (Py_ssize_t i = 0; i < 8 * groups; ++i)
        if (slots[i] < 0 || slots[i] >= n) {
            PyErr_SetString(PyExc_IndexError, "slot out of range");
            return -1;
        }
    for (Py_ssize_t e = 0; e < fills; ++e)
        if (to[e] < 0 || to[e] >= n || from[e] < 0 || from[e] >= n || !gutter[to[e]] ||
            gutter[from[e]]) {
            PyErr_SetString(PyExc_IndexError,
                            "a fill entry must take a covered texel into a gutter one");
            return -1;
        }
    if (n >= INT32_MAX) {
        PyErr_SetString(PyExc_ValueError, "too many unknowns");
        return -1;
    }
    out->ints = PyMem_RawCalloc((size_t)(3 * n + 1 + fills + 1), sizeof(int64_t));
    if (!out->ints) {
        PyErr_NoMemory();
        return -1;
    }
    out->cidx = out->ints;
    out->texel = out->cidx + n;
    out->to_ptr = out->texel + n;
    out->to_list = out->to_ptr + (n + 1);
    Py_ssize_t nc = 0;
    for (Py_ssize_t i = 0; i < n; ++i) {
        out->cidx[i] = gutter[i] ? -1 : nc;
        if (!gutter[i])
            out->texel[nc++] = i;
    }
    out->nc = nc;
    gather_lists(to, fills, n, out->to_ptr, out->to_list);
    return 0;
}

static Py_ssize_t clamp_threads(Py_ssize_t threads, Py_ssize_t rows)
{
    if (threads > SEAM_MAX_THREADS)
        threads = SEAM_MAX_THREADS;
    if (threads > rows)
        threads = rows > 0 ? rows : 1;
    return threads;
}

/* seam_pattern(starts, slots, gutter, fill_to, fill_from, threads=1) -> (indptr, indices)
 *
 * The pattern of the seam erasure's normal matrix A = W + P^T S P over the covered unknowns
 * (numbered in texel order, skipping the gutter ones): indptr (nc + 1,) int64 and indices
 * (nnz,) int32 bytes, each row's columns ascending, every diagonal stored.  It depends on
 * the system only, not on the baked values, so the seam system's thread makes it while the
 * samples are traced.  starts (G + 1,) int64 the groups' first points, slots (G, 8) int64 in
 * 0..n-1, gutter (n,) bool, fill_* (e,) int64 (fill_to a gutter texel, fill_from a covered
 * one).  Rows split over `threads` (the same pattern for any number). */
static PyObject *seam_pattern(PyObject *self, PyObject *args)
{
    Py_buffer bstarts = {0}, bslots = {0}, bgut = {0}, bto = {0}, bfrom = {0};
    Py_ssize_t threads = 1;
    Numbering N = {0};
    int64_t *in_j = NULL, *in_ptr = NULL, *indptr = NULL;
    PyObject *result = NULL, *pi = NULL, *px = NULL;
    AssembleWork work[SEAM_MAX_THREADS];
    Py_ssize_t shares = 0;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*|n", &bstarts, &bslots, &bgut, &bto, &bfrom, &threads))
        return NULL;
    if (threads < 1) {
        PyErr_SetString(PyExc_ValueError, "threads must be at least 1");
        goto done;
    }
    if (seam_numbering(&bstarts, &bslots, &bgut, &bto, &bfrom, -1, &N) < 0)
        goto done;
    {
        const Py_ssize_t groups = bslots.len / 64, nc = N.nc;
        const int64_t *slots = bslots.buf, *from = bfrom.buf;
        const uint8_t *gutter = bgut.buf;
        const int64_t *cidx = N.cidx, *to_ptr = N.to_ptr, *to_list = N.to_list;
        Py_ssize_t incoming = 0;  /* (slot, unknown) pairs over all slots' maps */
        for (Py_ssize_t j = 0; j < 8 * groups; ++j) {
            const int64_t t = slots[j];
            incoming += gutter[t] ? to_ptr[t + 1] - to_ptr[t] : 1;
        }
        in_ptr = PyMem_RawCalloc((size_t)(nc + 2), sizeof(int64_t));
        in_j = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(incoming + 1));
        indptr = PyMem_RawCalloc((size_t)(nc + 1), sizeof(int64_t));
        if (!in_ptr || !in_j || !indptr) {
            PyErr_NoMemory();
            goto done;
        }
        const Maps M = {slots, from, cidx, to_ptr, to_list, gutter, NULL};
        Py_BEGIN_ALLOW_THREADS
        /* per unknown a, the slots j whose map holds it, ascending j (a counting sort of
         * the (j, a) pairs, made in ascending j) */
        for (int pass = 0; pass < 2; ++pass) {
            for (Py_ssize_t j = 0; j < 8 * groups; ++j) {
                const int64_t t = slots[j];
                if (!gutter[t]) {
                    const int64_t a = cidx[t];
                    if (pass == 0) ++in_ptr[a + 1]; else in_j[in_ptr[a]++] = j;
                    continue;
                }
                for (int64_t q = to_ptr[t]; q < to_ptr[t + 1]; ++q) {
                    const int64_t a = cidx[from[to_list[q]]];
                    if (pass == 0) ++in_ptr[a + 1]; else in_j[in_ptr[a]++] = j;
                }
            }
            if (pass == 0)
                for (Py_ssize_t a = 0; a < nc; ++a)
                    in_ptr[a + 1] += in_ptr[a];
        }
        for (Py_ssize_t a = nc; a > 0; --a)  /* in_ptr[a] ran to the end of list a */
            in_ptr[a] = in_ptr[a - 1];
        in_ptr[0] = 0;
        Py_END_ALLOW_THREADS
        /* each share's rows on a thread (rows split by their incoming slots) */
        shares = clamp_threads(threads, nc);
        int failed = 0;
        for (Py_ssize_t k = 0, a = 0; k < shares; ++k) {
            AssembleWork t = {&M, in_ptr, in_j, NULL, NULL, NULL, NULL, NULL, NULL, groups,
                              a, a, 0, 0, NULL, NULL, NULL, NULL, 0, 0};
            const int64_t target = in_ptr[nc] * (k + 1) / shares;
            while (a < nc && (k == shares - 1 || in_ptr[a] < target))
                ++a;
            t.r1 = a;
            t.mark = PyMem_RawMalloc(sizeof(int32_t) * (size_t)(nc + 1));
            t.row_cols = PyMem_RawMalloc(sizeof(int32_t) * (size_t)(nc + 1));
            t.counts = indptr + 1;  /* each row's count, summed in place below */
            failed |= !t.mark || !t.row_cols;
            work[k] = t;
        }
        if (!failed) {
            Py_BEGIN_ALLOW_THREADS
            for (Py_ssize_t k = 0; k < shares; ++k)
                for (Py_ssize_t b = 0; b < nc; ++b)
                    work[k].mark[b] = -1;
            assemble_run(work, shares);
            Py_END_ALLOW_THREADS
            for (Py_ssize_t k = 0; k < shares; ++k)
                failed |= work[k].failed;
        }
        if (failed) {
            PyErr_NoMemory();
            goto done;
        }
        for (Py_ssize_t a = 0; a < nc; ++a)
            indptr[a + 1] += indptr[a];
        const Py_ssize_t nnz = indptr[nc];
        px = PyBytes_FromStringAndSize(NULL, 4 * nnz);
        pi = PyBytes_FromStringAndSize((const char *)indptr, 8 * (nc + 1));
        if (!px || !pi)
            goto done;
        int32_t *indices = (int32_t *)PyBytes_AS_STRING(px);
        for (Py_ssize_t k = 0; k < shares; ++k)
            if (work[k].nnz)
                memcpy(indices + indptr[work[k].r0], work[k].cols,
                       sizeof(int32_t) * (size_t)work[k].nnz);
        result = Py_BuildValue("(OO)", pi, px);
    }
done:
    for (Py_ssize_t k = 0; k < shares; ++k) {
        PyMem_RawFree(work[k].mark);
        PyMem_RawFree(work[k].row_cols);
        PyMem_RawFree(work[k].cols);
    }
    Py_XDECREF(pi); Py_XDECREF(px);
    PyMem_RawFree(N.ints); PyMem_RawFree(in_ptr); PyMem_RawFree(in_j); PyMem_RawFree(indptr);
    PyBuffer_Release(&bstarts); PyBuffer_Release(&bslots); PyBuffer_Release(&bgut);
    PyBuffer_Release(&bto); PyBuffer_Release(&bfrom);
    return result;
}

/* Checks a CSR pattern of n rows: indptr (n + 1,) from 0 to nnz, non-decreasing (with
 * `nonempty`, increasing: every row holds its diagonal), indices in 0..n-1; -1 with an
 * exception set. */
static int check_csr(const int64_t *indptr, const int32_t *indices, Py_ssize_t n,
                     Py_ssize_t nnz, int nonempty)
{
    if (indptr[0] != 0 || indptr[n] != nnz) {
        PyErr_SetString(PyExc_ValueError, "indptr must run from 0 to nnz");
        return -1;
    }
    for (Py_ssize_t i = 0; i < n; ++i)
        if (indptr[i] > indptr[i + 1] || (nonempty && indptr[i] == indptr[i + 1])) {
            PyErr_SetString(PyExc_ValueError, nonempty ? "a row without entries: not this pattern"
                                                       : "indptr must be non-decreasing");
            return -1;
        }
    for (Py_ssize_t j = 0; j < nnz; ++j)
        if (indices[j] < 0 || indices[j] >= n) {
            PyErr_SetString(PyExc_IndexError, "column out of range");
            return -1;
        }
    return 0;
}

/* seam_values(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w, indptr,
 *             indices, threads=1) -> data (nnz,) float64 bytes
 *
 * The values of A on seam_pattern's pattern (indptr, indices), in the arithmetic of
 * aobake.targets.texels.seams._assemble_numpy: coef (m, 8), lam (m,) float64, w (n,)
 * float64, the rest as for seam_pattern.  Every share reads the groups in order and adds its
 * own rows' terms (each group's block made just before its terms), so every entry's sum is
 * the reference's whatever the number of threads. */
static PyObject *seam_values(PyObject *self, PyObject *args)
{
    Py_buffer bcoef = {0}, blam = {0}, bstarts = {0}, bslots = {0}, bgut = {0};
    Py_buffer bto = {0}, bfrom = {0}, bfw = {0}, bw = {0}, bptr = {0}, bidx = {0};
    Py_ssize_t threads = 1;
    Numbering N = {0};
    PyObject *result = NULL, *pd = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*y*y*y*y*|n", &bcoef, &blam, &bstarts, &bslots,
                          &bgut, &bto, &bfrom, &bfw, &bw, &bptr, &bidx, &threads))
        return NULL;
    if (threads < 1) {
        PyErr_SetString(PyExc_ValueError, "threads must be at least 1");
        goto done;
    }
    {
        const Py_ssize_t m = blam.len / 8, n = bgut.len, fills = bto.len / 8;
        if (check(&bcoef, "coef", 8, 8 * m) || check(&blam, "lam", 8, m) ||
            check(&bfw, "fill_weight", 8, fills) || check(&bw, "w", 8, n) ||
            seam_numbering(&bstarts, &bslots, &bgut, &bto, &bfrom, m, &N) < 0)
            goto done;
        const Py_ssize_t nc = N.nc, groups = bslots.len / 64, nnz = bidx.len / 4;
        if (check(&bptr, "indptr", 8, nc + 1) || check(&bidx, "indices", 4, nnz))
            goto done;
        const int64_t *indptr = bptr.buf;
        const int32_t *indices = bidx.buf;
        if (check_csr(indptr, indices, nc, nnz, 1) < 0)  /* every row holds its diagonal */
            goto done;
        pd = PyBytes_FromStringAndSize(NULL, 8 * nnz);
        if (!pd)
            goto done;
        double *data = (double *)PyBytes_AS_STRING(pd);
        const Maps M = {bslots.buf, bfrom.buf, N.cidx, N.to_ptr, N.to_list, bgut.buf, bfw.buf};
        const Py_ssize_t shares = clamp_threads(threads, nc);
        AssembleWork work[SEAM_MAX_THREADS];
        for (Py_ssize_t k = 0; k < shares; ++k) {
            AssembleWork t = {&M, NULL, NULL, bstarts.buf, indptr, indices, bcoef.buf, blam.buf,
                              data, groups, nc * k / shares, nc * (k + 1) / shares, 0, 0,
                              NULL, NULL, NULL, NULL, 1, 0};
            work[k] = t;
        }
        const double *w = bw.buf;
        const int64_t *texel = N.texel;
        int missing = 0;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t u = 0; u < nnz; ++u)
            data[u] = 0.0;
        assemble_run(work, shares);
        /* the diagonal: + 0.0 (the reference's entry that makes sure it is stored), + w */
        for (Py_ssize_t a = 0; a < nc; ++a) {
            int64_t u = indptr[a];
            while (u < indptr[a + 1] && indices[u] != a)
                ++u;
            if (u == indptr[a + 1])
                missing = 1;
            else
                data[u] = (data[u] + 0.0) + w[texel[a]];
        }
        Py_END_ALLOW_THREADS
        if (missing) {
            PyErr_SetString(PyExc_ValueError, "a row without its diagonal: not this pattern");
            goto done;
        }
        result = pd;
        pd = NULL;
    }
done:
    Py_XDECREF(pd);
    PyMem_RawFree(N.ints);
    PyBuffer_Release(&bcoef); PyBuffer_Release(&blam); PyBuffer_Release(&bstarts);
    PyBuffer_Release(&bslots); PyBuffer_Release(&bgut); PyBuffer_Release(&bto);
    PyBuffer_Release(&bfrom); PyBuffer_Release(&bfw); PyBuffer_Release(&bw);
    PyBuffer_Release(&bptr); PyBuffer_Release(&bidx);
    return result;
}

/* The CG's threads: each its share of rows (split by entries), all running the same loop. */
typedef struct {
    const int64_t *indptr;
    const int32_t *indices;
    const double *data, *diag, *b, *rhs;
    Barrier *barrier;
    double *x, *r, *z, *p, *q;
    Py_ssize_t n, i0, i1;
    double tolerance;
    Py_ssize_t max_iterations;
    Py_ssize_t iterations;  /* out (the same in every thread) */
    double left;
} CsrWork;

/* out = A x on this thread's rows; returns after every thread's rows are done. */
static void csr_apply(const CsrWork *t, const double *x, double *out)
{
    for (Py_ssize_t i = t->i0; i < t->i1; ++i) {
        double s = 0.0;
        for (int64_t j = t->indptr[i]; j < t->indptr[i + 1]; ++j)
            s += t->data[j] * x[t->indices[j]];
        out[i] = s;
    }
    barrier_wait(t->barrier);
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

/* The whole conjugate-gradient loop, as every thread runs it on its rows.  The dot
 * products and the stopping test run over all rows in every thread (each ~0.1 ms), so the
 * threads take the same steps without one broadcasting them. */
static void csr_cg_share(CsrWork *t)
{
    const Py_ssize_t n = t->n, i0 = t->i0, i1 = t->i1;
    const double *diag = t->diag, *b = t->b, *rhs = t->rhs;
    double *x = t->x, *r = t->r, *z = t->z, *p = t->p, *q = t->q;
    for (Py_ssize_t i = i0; i < i1; ++i)
        x[i] = b[i];
    barrier_wait(t->barrier);
    csr_apply(t, x, q);
    for (Py_ssize_t i = i0; i < i1; ++i) {
        r[i] = rhs[i] - q[i];
        z[i] = r[i] / diag[i];
        p[i] = z[i];
    }
    barrier_wait(t->barrier);
    double rz = seq_dot(r, z, n);
    Py_ssize_t it = 0;
    while (max_abs(z, n) > t->tolerance && it < t->max_iterations) {
        csr_apply(t, p, q);
        const double alpha = rz / seq_dot(p, q, n);
        for (Py_ssize_t i = i0; i < i1; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
            z[i] = r[i] / diag[i];
        }
        barrier_wait(t->barrier);
        const double rz_old = rz;
        rz = seq_dot(r, z, n);
        const double beta = rz / rz_old;
        /* every thread has read z (max_abs) and r, z (the dot) before p changes: p is read
         * only by the next csr_apply, after this barrier */
        for (Py_ssize_t i = i0; i < i1; ++i)
            p[i] = z[i] + beta * p[i];
        barrier_wait(t->barrier);
        ++it;
    }
    t->iterations = it;
    t->left = max_abs(z, n);
}

#ifndef _WIN32
static void *csr_cg_thread(void *arg)
{
    CsrWork *t = arg;
    Barrier *b = t->barrier;
    if (barrier_gate(b))
        csr_cg_share(t);
    return NULL;
}
#endif

/* seam_csr_cg(indptr, indices, data, diag, rhs, b, x, tolerance, max_iterations, threads)
 *     -> (iterations, the last max |r / diag|)
 *
 * Jacobi-preconditioned conjugate gradients on A x = rhs from x = b (A as seam_values
 * makes it, n rows), stopping when max |r / diag| <= tolerance or after max_iterations:
 * aobake.targets.texels.seams._cg_numpy operation for operation (tested bit for bit), on
 * `threads` threads splitting the rows (the same bits for any number: every row's sum is
 * made by one thread, in column order). */
static PyObject *seam_csr_cg(PyObject *self, PyObject *args)
{
    Py_buffer bptr = {0}, bidx = {0}, bdata = {0}, bdiag = {0}, brhs = {0}, bb = {0}, bx = {0};
    double tolerance;
    Py_ssize_t max_iterations, threads = 1, it = 0;
    double left = 0.0;
    double *scratch = NULL;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*w*dn|n", &bptr, &bidx, &bdata, &bdiag, &brhs, &bb,
                          &bx, &tolerance, &max_iterations, &threads))
        return NULL;
    {
        const Py_ssize_t n = bdiag.len / 8, nnz = bdata.len / 8;
        if (check(&bptr, "indptr", 8, n + 1) || check(&bidx, "indices", 4, nnz) ||
            check(&bdata, "data", 8, nnz) || check(&bdiag, "diag", 8, n) ||
            check(&brhs, "rhs", 8, n) || check(&bb, "b", 8, n) || check(&bx, "x", 8, n))
            goto done;
        if (threads < 1) {
            PyErr_SetString(PyExc_ValueError, "threads must be at least 1");
            goto done;
        }
        const int64_t *indptr = bptr.buf;
        const int32_t *indices = bidx.buf;
        if (check_csr(indptr, indices, n, nnz, 0) < 0)
            goto done;
        scratch = PyMem_RawMalloc(sizeof(double) * (size_t)(4 * n + 1));
        if (!scratch) {
            PyErr_NoMemory();
            goto done;
        }
#ifdef _WIN32
        threads = 1;
#endif
        if (threads > SEAM_MAX_THREADS)
            threads = SEAM_MAX_THREADS;
        CsrWork work[SEAM_MAX_THREADS];
        Barrier barrier;
        barrier.count = (int)threads;
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t k = 0; k < threads; ++k) {
            CsrWork t = {indptr, indices, bdata.buf, bdiag.buf, bb.buf, brhs.buf, &barrier,
                         bx.buf, scratch, scratch + n, scratch + 2 * n, scratch + 3 * n, n,
                         0, 0, tolerance, max_iterations, 0, 0.0};
            work[k] = t;
        }
        /* rows split by their entries: the first row whose entries start at or past k/T */
        for (Py_ssize_t k = 0, i = 0; k < threads; ++k) {
            work[k].i0 = i;
            const int64_t target = nnz * (k + 1) / threads;
            while (i < n && (k == threads - 1 || indptr[i] < target))
                ++i;
            work[k].i1 = i;
        }
#ifndef _WIN32
        if (threads > 1) {
            pthread_t handles[SEAM_MAX_THREADS];
            Py_ssize_t started = 1;
            pthread_mutex_init(&barrier.lock, NULL);
            pthread_cond_init(&barrier.turn, NULL);
            barrier.waiting = barrier.generation = barrier.gate = 0;
            for (; started < threads; ++started)
                if (pthread_create(&handles[started], NULL, csr_cg_thread, &work[started]))
                    break;
            barrier_open(&barrier, started == threads ? 1 : -1);
            if (started == threads)
                csr_cg_share(&work[0]);
            for (Py_ssize_t k = 1; k < started; ++k)
                pthread_join(handles[k], NULL);
            pthread_mutex_destroy(&barrier.lock);
            pthread_cond_destroy(&barrier.turn);
            if (started < threads)  /* no threads to be had: all of it on this one */
                threads = barrier.count = 1;
        }
#endif
        if (threads == 1) {
            work[0].i0 = 0;
            work[0].i1 = n;
            csr_cg_share(&work[0]);
        }
        it = work[0].iterations;
        left = work[0].left;
        Py_END_ALLOW_THREADS
    }
    result = Py_BuildValue("nd", it, left);
done:
    PyMem_RawFree(scratch);
    PyBuffer_Release(&bptr); PyBuffer_Release(&bidx); PyBuffer_Release(&bdata);
    PyBuffer_Release(&bdiag); PyBuffer_Release(&brhs); PyBuffer_Release(&bb);
    PyBuffer_Release(&bx);
    return result;
}

/* dilate_rings(out, filled, height, width, channels, padding) -> rings filled
 *
 * aobake.post.dilate's rings, in place: out (H*W*C,) float64 the image (background zeroed),
 * filled (H*W,) bool.  A ring is every texel not filled with a filled 8-neighbour (as
 * filled before the ring); each becomes the mean of those neighbours, summed in the order
 * of aobake.post._NEIGHBOURS from 0.0 and divided by their count: the numpy formulation's
 * operations (tested bit for bit).  Ring texels are never a neighbour read in their own
 * ring (they are not filled yet), so they are written in place and marked after the ring.
 */
static PyObject *dilate_rings(PyObject *self, PyObject *args)
{
    Py_buffer bout = {0}, bfill = {0};
    Py_ssize_t h, w, c, padding, rings = 0;
    int64_t *ring = NULL;
    PyObject *result = NULL;
    static const int DR[8] = {-1, -1, -1, 0, 0, 1, 1, 1}, DC[8] = {-1, 0, 1, -1, 1, -1, 0, 1};
    (void)self;
    if (!PyArg_ParseTuple(args, "w*w*nnnn", &bout, &bfill, &h, &w, &c, &padding))
        return NULL;
    if (h < 0 || w < 0 || c < 1 || padding < 0) {
        PyErr_SetString(PyExc_ValueError, "dilate_rings: bad shape or padding");
        goto done;
    }
    if (check(&bout, "out", 8, h * w * c) || check(&bfill, "filled", 1, h * w))
        goto done;
    ring = PyMem_RawMalloc(sizeof(int64_t) * (size_t)(h * w + 1));
    if (!ring) {
        PyErr_NoMemory();
        goto done;
    }
    {
        double *out = bout.buf;
        uint8_t *filled = bfill.buf;
        Py_BEGIN_ALLOW_THREADS
        for (; rings < padding; ++rings) {
            Py_ssize_t k = 0;
            for (Py_ssize_t r = 0; r < h; ++r)
                for (Py_ssize_t col = 0; col < w; ++col) {
                    const Py_ssize_t t = r * w + col;
                    if (filled[t])
                        continue;
                    for (int j = 0; j < 8; ++j) {
                        const Py_ssize_t rr = r + DR[j], cc = col + DC[j];
                        if (rr >= 0 && rr < h && cc >= 0 && cc < w && filled[rr * w + cc]) {
                            ring[k++] = t;
                            break;
                        }
                    }
                }
            if (k == 0)
                break;
            for (Py_ssize_t i = 0; i < k; ++i) {
                const Py_ssize_t t = ring[i], r = t / w, col = t % w;
                double *dst = out + t * c;
                double count = 0.0;
                for (Py_ssize_t ch = 0; ch < c; ++ch)
                    dst[ch] = 0.0;
                for (int j = 0; j < 8; ++j) {
                    const Py_ssize_t rr = r + DR[j], cc = col + DC[j];
                    if (rr < 0 || rr >= h || cc < 0 || cc >= w || !filled[rr * w + cc])
                        continue;
                    const double *src = out + (rr * w + cc) * c;
                    for (Py_ssize_t ch = 0; ch < c; ++ch)
                        dst[ch] += src[ch];
                    count += 1.0;
                }
                for (Py_ssize_t ch = 0; ch < c; ++ch)
                    dst[ch] = dst[ch] / count;
            }
            for (Py_ssize_t i = 0; i < k; ++i)
                filled[ring[i]] = 1;
        }
        Py_END_ALLOW_THREADS
    }
    result = PyLong_FromSsize_t(rings);

done:
    PyMem_RawFree(ring);
    PyBuffer_Release(&bout); PyBuffer_Release(&bfill);
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
static PyObject *surface_shading(PyObject *self, PyObject *args)
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

/* The atlas packer's kernels, in _pack.c. */
PyObject *chart_marks(PyObject *self, PyObject *args);
PyObject *pack_charts(PyObject *self, PyObject *args);

static PyMethodDef methods[] = {
    {"fill_rays", fill_rays, METH_VARARGS,
     "fill_rays(origins, normals, keys, table, sampler, weighting, nx, ny, k, R, m, js, mp, "
     "out_origins, out_directions): write point-major ray origins and directions."},
    {"raster_rows", raster_rows, METH_VARARGS,
     "raster_rows(ax, ay, dx, dy, owner, corner, vmax, verts, c0, c1, row_start, row_tris, width, "
     "n_sub, seed_key, q, g, row_lo, row_hi, write, rows, out_texel, out_face, out_bary, "
     "out_sample, out_fallback, coverage, shared): the rasteriser, rows in final order."},
    {"row_counts", row_counts, METH_VARARGS,
     "row_counts(flags, rows, m, out): nonzero flags per row of m."},
    {"radix_argsort", radix_argsort, METH_VARARGS,
     "radix_argsort(keys, bits, out_order, out_sorted): stable argsort of uint32 keys."},
    {"surface_interp", surface_interp, METH_VARARGS,
     "surface_interp(positions, normals, faces, face, bary, out_points, out_normals, out_length): "
     "lightmap sample points and unit shading normals."},
    {"surface_shading", surface_shading, METH_VARARGS,
     "surface_shading(face, unit, has_face, turned, normals, length, out) -> (fixed, turned): "
     "lightmap samples' shading normals (surface_points' rule)."},
    {"dilate_rings", dilate_rings, METH_VARARGS,
     "dilate_rings(out, filled, height, width, channels, padding) -> rings: "
     "aobake.post.dilate's rings in place"},
    {"seam_pattern", seam_pattern, METH_VARARGS,
     "seam_pattern(starts, slots, gutter, fill_to, fill_from[, threads]) -> (indptr, indices) "
     "bytes: the seam erasure's normal matrix's CSR pattern."},
    {"seam_values", seam_values, METH_VARARGS,
     "seam_values(coef, lam, starts, slots, gutter, fill_to, fill_from, fill_weight, w, indptr, "
     "indices[, threads]) -> data bytes: its values on that pattern."},
    {"seam_csr_cg", seam_csr_cg, METH_VARARGS,
     "seam_csr_cg(indptr, indices, data, diag, rhs, b, x, tolerance, max_iterations[, threads]) "
     "-> (iterations, max |r / diag|): the seam erasure's Jacobi-preconditioned CG."},
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
