/* aobake._kernels, a box-filtered view's rays (aobake.targets.view_box), compiled:
 * pixel_rays, the positions of the joint estimator's sobol samples in their pixels
 * (aobake.samplers.joint.positions, "sobol") and the camera rays through them
 * (view_box._Context.directions); box_rays, the AO rays from those rays' hits
 * (view_box._Context.hits, _offsets, _ao_rays).
 *
 * Why: in numpy these are whole-array passes per block that hold the GIL between them,
 * about a third of a view's CPU time and what kept a second thread from helping (measured
 * on the still life at 160x90, 256 rays per pixel: ~130 of 380 ms on one thread; two
 * threads took 0.32 s where one took 0.40 s).  Here one pass each, the GIL released.  numpy stays the reference and the fallback; tests check the two agree bit for
 * bit (tests/test_view_box_stratified.py).
 *
 * Exactness: the scrambles are uint32 arithmetic (wrapping, as numpy's); the directions are
 * single IEEE-754 operations in numpy's order and precision (setup.py: -ffp-contract=off),
 * sqrt correctly rounded in both.
 */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>

/* aobake.rng.dim_salt(d), d = 0..4: the salts of aobake.samplers.joint.seeds */
static const uint64_t SALTS[5] = {0x632BE59BD9B4E019ULL, 0xC657CB37B369C032ULL,
                                  0x2983B0D38D1EA04BULL, 0x8CAF966F66D38064ULL,
                                  0xEFDB7C0B4088607DULL};

/* pixel_rays(pixels, keys, net, R, q0, count, m, width, height, sx, sy, half_w, half_h,
 *            basis, out_where, out_directions, out_directions32)
 *
 * pixels      (k,)            int64    the pixels (row-major index, >= 0)
 * keys        (k, R)          uint64   their replicates' keys (samplers.base.replicate_keys)
 * net         (m, 2)          uint32   the first m points of the 2-D Sobol sequence, bits
 *                                      reversed (joint.net_reversed(m), interleaved)
 * q0, count   slots q0 .. q0 + count - 1 of every replicate; m positions per replicate
 * sx, sy      2.0 / width, 2.0 / height (as Python computes them)
 * half_w, half_h  the view's half extents at distance 1
 * basis       (3, 3)          float64  the camera's right, up and forward vectors (rows)
 * out_where   (k*R*count, 2)  float64  written: each position in its pixel (x right, y down)
 * out_directions   (k*R*count, 3) float64  written: the unit ray direction through it
 * out_directions32 (k*R*count, 3) float32  written: the same, rounded to float32
 *
 * Rows pixel-major, then replicate, then slot, as view_box._item orders them.
 */
PyObject *pixel_rays(PyObject *self, PyObject *args)
{
    Py_buffer pix = {0}, keyb = {0}, netb = {0}, basisb = {0}, ow = {0}, od = {0}, od32 = {0};
    Py_ssize_t R, q0, count, m, width, height;
    double sx, sy, half_w, half_h;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*nnnnnnddddy*w*w*w*", &pix, &keyb, &netb, &R, &q0,
                          &count, &m, &width, &height, &sx, &sy, &half_w, &half_h, &basisb,
                          &ow, &od, &od32))
        return NULL;
    const Py_ssize_t k = pix.len / 8;
    if (R < 1 || q0 < 0 || count < 0 || m < 1 || m > 0x7FFFFFFF || q0 + count > m ||
        width < 1 || height < 1) {
        PyErr_SetString(PyExc_ValueError, "bad sizes");
        goto done;
    }
    if (check(&pix, "pixels", 8, k) || check(&keyb, "keys", 8, k * R) ||
        check(&netb, "net", 4, 2 * m) || check(&basisb, "basis", 8, 9) ||
        check(&ow, "out_where", 8, k * R * count * 2) ||
        check(&od, "out_directions", 8, k * R * count * 3) ||
        check(&od32, "out_directions32", 4, k * R * count * 3))
        goto done;

    {
        const int64_t *pixels = (const int64_t *)pix.buf;
        const uint64_t *keys = (const uint64_t *)keyb.buf;
        const uint32_t *net = (const uint32_t *)netb.buf;
        const double *b = (const double *)basisb.buf;
        double *where = (double *)ow.buf, *dir = (double *)od.buf;
        float *dir32 = (float *)od32.buf;
        /* joint.shuffle's mask: the low bits that permute 0..M-1, M the power of two >= m */
        int bits = 0;
        while (bits < 32 && ((uint64_t)1 << bits) < (uint64_t)m)
            ++bits;
        const uint32_t mask = bits < 32 ? (uint32_t)((1ULL << bits) - 1) : 0xFFFFFFFFu;
        int bad = 0;

        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t p = 0; p < k && !bad; ++p) {
            if (pixels[p] < 0) {
                bad = 1;
                break;
            }
            const int64_t row = pixels[p] / width, column = pixels[p] % width;
            for (Py_ssize_t g = 0; g < R; ++g) {
                const uint64_t key = keys[p * R + g];
                uint32_t seed[5];
                for (int d = 0; d < 5; ++d)
                    seed[d] = (uint32_t)(mix(key + SALTS[d]) >> 32);
                for (Py_ssize_t i = 0; i < count; ++i) {
                    /* joint.shuffle: the Owen scramble of the slot, walked below m */
                    uint32_t slot = reverse32(lk_permute(reverse32((uint32_t)(q0 + i)),
                                                      seed[4])) & mask;
                    while (slot >= (uint32_t)m)
                        slot = reverse32(lk_permute(reverse32(slot), seed[4])) & mask;
                    /* joint._scramble of point `slot` of the net: its cell's centre */
                    const double ux = (double)reverse32(lk_permute(net[2 * slot], seed[0]))
                                      * 0x1p-32 + 0x1p-33;
                    const double uy = (double)reverse32(lk_permute(net[2 * slot + 1], seed[1]))
                                      * 0x1p-32 + 0x1p-33;
                    /* view_box._Context.directions */
                    const double vx = (((double)column + ux) * sx - 1.0) * half_w;
                    const double vy = (1.0 - ((double)row + uy) * sy) * half_h;
                    double d[3];
                    for (int a = 0; a < 3; ++a)
                        d[a] = (vx * b[a] + vy * b[3 + a]) + b[6 + a];
                    const double norm = sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2]);
                    const Py_ssize_t row_out = (p * R + g) * count + i;
                    where[2 * row_out] = ux;
                    where[2 * row_out + 1] = uy;
                    for (int a = 0; a < 3; ++a) {
                        const double unit = d[a] / norm;
                        dir[3 * row_out + a] = unit;
                        dir32[3 * row_out + a] = (float)unit;
                    }
                }
            }
        }
        Py_END_ALLOW_THREADS
        if (bad) {
            PyErr_SetString(PyExc_ValueError, "negative pixel index");
            goto done;
        }
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&pix);
    PyBuffer_Release(&keyb);
    PyBuffer_Release(&netb);
    PyBuffer_Release(&basisb);
    PyBuffer_Release(&ow);
    PyBuffer_Release(&od);
    PyBuffer_Release(&od32);
    return result;
}

/* box_rays(directions, t, prim, faces, eye, center, scale, up, height, ground_size,
 *          fraction, ulps, keys, slots, table, sampler, weighting, r, m,
 *          out_origins, out_directions)
 *
 * The AO rays of h positions whose primary rays hit: each hit point and its geometric
 * normal facing the eye (view_box._Context.hits), its ray origin lifted off the surface
 * (view_box._offsets, as aobake.offsets.point_offsets), and its r rays (fill_rays' loop):
 * the numpy of view_box._ao_rays, bit for bit, in position order.
 *
 * directions (h, 3) float64   the primary rays' unit directions (scene frame)
 * t          (h,)   float32   Embree's distances (local units)
 * prim       (h,)   int64     the face hit, -1 for the ground plane
 * faces      (F, 5) float64   per face: unit normal, n . (v0 - eye), the offset's scale
 * eye, center (3,)  float64;  scale: local units per scene unit
 * up         the ground plane's axis (-1: no plane), height its height, ground_size its
 *            offset scale (local units)
 * fraction   --ray-offset; ulps: aobake.constants.OFFSET_ULPS
 * keys       (h,)   uint64    each position's replicate's direction key
 * slots      (h,)   int64     each position's slot q in its replicate: rays q r .. q r + r - 1
 * table      (T, 2) uint32    sobol: the replicate's bit-reversed net (T >= m); random: empty
 * sampler    0 random (one ray per position, on the key hashed with its slot), 2 sobol
 * out_origins, out_directions (h r, 3) float32  written
 */
PyObject *box_rays(PyObject *self, PyObject *args)
{
    Py_buffer dirb = {0}, tb = {0}, primb = {0}, facesb = {0}, eyeb = {0}, centerb = {0},
              keyb = {0}, slotb = {0}, tab = {0}, oo = {0}, od = {0};
    double scale, height, ground_size, fraction, ulps;
    int up, sampler, weighting;
    Py_ssize_t r, m;
    PyObject *result = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*diddddy*y*y*iinnw*w*", &dirb, &tb, &primb,
                          &facesb, &eyeb, &centerb, &scale, &up, &height, &ground_size,
                          &fraction, &ulps, &keyb, &slotb, &tab, &sampler, &weighting, &r,
                          &m, &oo, &od))
        return NULL;
    const Py_ssize_t h = tb.len / 4, n_faces = facesb.len / 40, rows = tab.len / 8;
    if (r < 1 || m < 1 || up < -1 || up > 2 || (sampler != 0 && sampler != 2) ||
        weighting < 0 || weighting > 1 || (sampler == 0 && r != 1)) {
        PyErr_SetString(PyExc_ValueError, "bad sampler, weighting or sizes");
        goto done;
    }
    if (check(&dirb, "directions", 8, 3 * h) || check(&tb, "t", 4, h) ||
        check(&primb, "prim", 8, h) || check(&facesb, "faces", 8, 5 * n_faces) ||
        check(&eyeb, "eye", 8, 3) || check(&centerb, "center", 8, 3) ||
        check(&keyb, "keys", 8, h) || check(&slotb, "slots", 8, h) ||
        check(&tab, "table", 4, 2 * rows) || check(&oo, "out_origins", 4, 3 * h * r) ||
        check(&od, "out_directions", 4, 3 * h * r))
        goto done;

    {
        const double *dir = (const double *)dirb.buf, *faces = (const double *)facesb.buf;
        const double *eye = (const double *)eyeb.buf, *center = (const double *)centerb.buf;
        const float *t = (const float *)tb.buf;
        const int64_t *prim = (const int64_t *)primb.buf, *slots = (const int64_t *)slotb.buf;
        const uint64_t *keys = (const uint64_t *)keyb.buf;
        const uint32_t *table = (const uint32_t *)tab.buf;
        float *out_o = (float *)oo.buf, *out_d = (float *)od.buf;
        int bad = 0;

        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t p = 0; p < h; ++p) {
            const double *d = dir + 3 * p;
            const int64_t face = prim[p];
            const double embree = (double)t[p] / scale;
            double ng[3], dn, along, size;
            if (face >= 0) {
                if (face >= n_faces) {
                    bad = 1;
                    break;
                }
                const double *f = faces + 5 * face;
                ng[0] = f[0];
                ng[1] = f[1];
                ng[2] = f[2];
                dn = (d[0] * ng[0] + d[1] * ng[1]) + d[2] * ng[2];
                along = fabs(dn) > 1e-9 ? f[3] / dn : embree;  /* view_box._GRAZING */
                if (!(isfinite(along) && along > 0.0))
                    along = embree;
                size = f[4];
            } else {
                if (up < 0) {
                    bad = 2;
                    break;
                }
                ng[0] = ng[1] = ng[2] = 0.0;
                ng[up] = 1.0;
                dn = d[up];
                along = (height - eye[up]) / d[up];
                size = ground_size;
            }
            double local[3];
            for (int a = 0; a < 3; ++a) {
                const double point = (face < 0 && a == up) ? height : eye[a] + along * d[a];
                local[a] = (point - center[a]) * scale;
            }
            const double flip = dn > 0.0 ? -1.0 : 1.0;  /* the side the eye sees */
            for (int a = 0; a < 3; ++a)
                ng[a] = ng[a] * flip;
            /* view_box._offsets: the larger of OFFSET_ULPS float32 ulps of the point's
             * magnitude and --ray-offset times its size */
            double biggest = fabs(local[0]) >= fabs(local[1]) ? fabs(local[0]) : fabs(local[1]);
            biggest = biggest >= fabs(local[2]) ? biggest : fabs(local[2]);
            const float magnitude = (float)(biggest + size);
            const double floor_ = ulps * (double)(nextafterf(magnitude, INFINITY) - magnitude);
            const double lift = fraction * size;
            const double offset = floor_ >= lift ? floor_ : lift;
            float origin[3];
            for (int a = 0; a < 3; ++a)
                origin[a] = (float)(local[a] + offset * ng[a]);
            const int64_t slot = slots[p];
            if (slot < 0 || (sampler == 2 && (slot + 1) * r > rows)) {
                bad = 3;
                break;
            }
            if (sampler == 2) {
                aobake_ray_loop(origin, ng, keys + p, table + 2 * slot * r, 2, weighting, 0, 0,
                                1, 1, slot * r, r, out_o + 3 * p * r, out_d + 3 * p * r);
            } else {  /* joint.hashes_at: the position's own key, its sample 0 */
                const uint64_t key = mix(keys[p] + (uint64_t)(slot + 1) * 0xD1B54A32D192ED03ULL);
                aobake_ray_loop(origin, ng, &key, table, 0, weighting, 0, 0, 1, 1, 0, 1,
                                out_o + 3 * p, out_d + 3 * p);
            }
        }
        Py_END_ALLOW_THREADS
        if (bad) {
            PyErr_SetString(PyExc_ValueError, bad == 1 ? "a face index beyond the faces" :
                            bad == 2 ? "a ground-plane hit without a ground plane" :
                            "a slot beyond the table");
            goto done;
        }
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    PyBuffer_Release(&dirb);
    PyBuffer_Release(&tb);
    PyBuffer_Release(&primb);
    PyBuffer_Release(&facesb);
    PyBuffer_Release(&eyeb);
    PyBuffer_Release(&centerb);
    PyBuffer_Release(&keyb);
    PyBuffer_Release(&slotb);
    PyBuffer_Release(&tab);
    PyBuffer_Release(&oo);
    PyBuffer_Release(&od);
    return result;
}
