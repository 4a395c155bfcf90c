/* aobake._kernels, the lightmap rasteriser: aobake.targets.texels.raster, compiled
 * (its numpy formulation is the reference: the same samples, bit for bit). */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

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

PyObject *raster_rows(PyObject *self, PyObject *args)
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
