/* aobake._kernels, a box-filtered view's primary rays: the positions of the joint
 * estimator's sobol samples in their pixels (aobake.samplers.joint.positions, "sobol") and
 * the camera rays through them (aobake.targets.view_box._Context.directions), compiled.
 *
 * Why: in numpy these are ~20 whole-array passes per block that hold the GIL between them,
 * a fifth of a view's CPU time and most of what kept a second thread from helping (measured
 * on the still life at 160x90, 256 rays per pixel: 76 of 380 ms on one thread; two threads
 * took 0.32 s where the GIL-free part alone would allow 0.25 s).  Here one pass, the GIL
 * released.  numpy stays the reference and the fallback; tests check the two agree bit for
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
