/* aobake._kernels, ray generation: the per-ray part of aobake.rays (the samplers of
 * aobake.samplers, the warps of aobake.warp), compiled.
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
 */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

/* The samplers of aobake.samplers, sample j of the replicate with key `key`. */
#define SALT0 0x632BE59BD9B4E019ULL  /* aobake.rng.dim_salt(0) */
#define SALT1 0xC657CB37B369C032ULL  /* aobake.rng.dim_salt(1) */
#define SAMPLE_STEP 0xD1B54A32D192ED03ULL  /* aobake.samplers.base.sample_hashes */

static inline double unit53(uint64_t h) { return (double)(h >> 11) * 0x1p-53; }

/* aobake.samplers.sobol.owen_scramble_reversed (Burley 2020, Laine-Karras permutation) of a
 * bit-reversed Sobol point (the table is stored reversed: one reversal per sample saved). */
#define BLOCK 64
static inline uint32_t owen_reversed(uint32_t x, uint32_t seed)
{
    return reverse32(lk_permute(x, seed));
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

/* The ray loop of fill_rays (and of _pixels.c's box_rays).  Compiled twice where the compiler can (GCC/clang on x86-64
 * Linux): for AVX2 and for the baseline, picked at load time by the CPU.  The AVX2 build
 * vectorises the Owen hash and the square roots (measured 15.5 -> 8.8 ns per ray); both
 * do the same IEEE operations (no contraction: -ffp-contract=off), so the rays are
 * bit-identical whichever runs. */
#if defined(__x86_64__) && defined(__linux__) && (defined(__GNUC__) || defined(__clang__))
__attribute__((target_clones("avx2", "default")))
#endif
void aobake_ray_loop(const float *o, const double *n, const uint64_t *keys, const uint32_t *tb,
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
PyObject *fill_rays(PyObject *self, PyObject *args)
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
        aobake_ray_loop(o, n, keys, tb, sampler, weighting, nx, ny, k, R, js, mp, oo, od);
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
