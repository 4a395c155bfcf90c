/* aobake._kernels, atlas packing: the hot loops of aobake.targets.texels.packing, compiled.
 *
 * A fresh atlas is packed by aobake itself (packing._layout): at each trial scale every
 * chart's texels are marked (packing._chart_masks: a conservative rasterisation of its
 * triangles, grown by `padding` rings) and the grown masks are laid into a strip
 * (packing._pack_in_order with packing._Packer: skyline drop over four quarter turns, hole
 * search, exhaustive search, then the skyline / free-run / free-square updates).  In numpy
 * that is ~1.1 s CPU of the bunny's ~3.3 s unwrap at 1024^2 P2 (4 packs, one thread);
 * here ~0.15 s (marks ~9 ms per scale, a pack ~20 ms); the ogre's 826 charts at 1024^2 P8
 * (6 packs) 3.9 -> 0.3 s.  Measured numbers for more cases: unwrap._xatlas_atlas.
 *
 * Where the time went, and what changed the order of work but never a result: the four
 * turns' column profiles come from one pass over the mask's rows' and columns' first and
 * last texels (only the turn placed is rotated); the skyline tries each window's columns
 * highest-reaching first and leaves a window once its drop reaches the lowest so far (it
 * can no longer be the first strict minimum np.argmin returns); a free-square refresh stops
 * at the largest square in its range (max(dy, .) >= dy changes nothing past it); the free
 * runs left of a placed chart are cut only where the cut is below HOLE_RUN.
 *
 * Exactness: the numpy formulations in packing.py are the reference and this file gives
 * the same bits (tests/test_pack_kernel.py).  The packer is integer arithmetic but for
 * its scores, y + the mean over a turn's marked columns of their one-past-last row, which
 * numpy computes as float64(sum) / count (every partial sum of the integer rows is exact
 * in float64) and which are computed the same way here, then compared with the same
 * strict `<` in the same order (skyline turns 0..3, then holes for turns 0 and 1, then the
 * exhaustive search).  Every search returns the first hit in numpy's order: np.argmin's
 * first minimum, raster order in the hole and exhaustive searches.  The marks start from
 * numpy's frame coordinates of the vertices; each triangle's edge functions are formed
 * from them with numpy's operations in numpy's order (edge_functions) and tested as
 * (a x + b y) + c >= 0 in float64, left to right (setup.py compiles with
 * -ffp-contract=off, so no multiply-add is fused).
 *
 * The packer's constants (HOLE_CAP, HOLE_RUN, HOLE_ROWS, MAX_SEARCHES) come from packing.py
 * as arguments, so there is one place that sets them.  No numpy C API (_kernels.h).
 */
#include "_kernels.h"
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>


/* Check per-mask offsets against shapes: offsets[0] = 0, offsets[c + 1] - offsets[c] =
 * shape[2c] * shape[2c + 1] (the mask's rows and columns, either order), offsets[k] = total. */
static int check_offsets(const int64_t *offset, const int64_t *shape, Py_ssize_t k,
                         Py_ssize_t total, const char *name)
{
    if (offset[0] != 0 || offset[k] != total) {
        PyErr_Format(PyExc_ValueError, "%s: offsets must run from 0 to %zd", name, total);
        return -1;
    }
    for (Py_ssize_t c = 0; c < k; ++c) {
        const int64_t a = shape[2 * c], b = shape[2 * c + 1];
        if (a < 0 || b < 0 || (b > 0 && a > INT64_MAX / b) ||
            offset[c + 1] - offset[c] != a * b) {
            PyErr_Format(PyExc_ValueError, "%s: mask %zd's offsets do not match its shape", name, c);
            return -1;
        }
    }
    return 0;
}

/* ---- chart marks (packing._chart_masks, packing._grow) -------------------------------- */

/* Grow an (h, w) mask by `rings` 8-neighbour rings (a square of side 2 rings + 1) into
 * `out`, through `tmp` (h * w bytes): a boolean dilation, so any order of ORs gives the
 * same marks as packing._grow's shifted ORs.  A running count per window keeps it O(h w). */
static void grow(const uint8_t *m, Py_ssize_t h, Py_ssize_t w, Py_ssize_t rings,
                 uint8_t *tmp, uint8_t *out)
{
    if (rings == 0) {
        if (h * w > 0)
            memcpy(out, m, (size_t)(h * w));
        return;
    }
    for (Py_ssize_t i = 0; i < h; ++i) {  /* along the rows: columns j - rings .. j + rings */
        const uint8_t *row = m + i * w;
        uint8_t *t = tmp + i * w;
        Py_ssize_t count = 0;
        for (Py_ssize_t j = 0; j < w && j < rings; ++j)
            count += row[j];
        for (Py_ssize_t j = 0; j < w; ++j) {
            if (j + rings < w)
                count += row[j + rings];
            if (j - rings - 1 >= 0)
                count -= row[j - rings - 1];
            t[j] = count > 0;
        }
    }
    for (Py_ssize_t j = 0; j < w; ++j) {  /* down the columns: rows i - rings .. i + rings */
        Py_ssize_t count = 0;
        for (Py_ssize_t i = 0; i < h && i < rings; ++i)
            count += tmp[i * w + j];
        for (Py_ssize_t i = 0; i < h; ++i) {
            if (i + rings < h)
                count += tmp[(i + rings) * w + j];
            if (i - rings - 1 >= 0)
                count -= tmp[(i - rings - 1) * w + j];
            out[i * w + j] = count > 0;
        }
    }
}

/* One triangle's marks, as packing._chart_masks computes them in numpy, operation for
 * operation: its corners p (3, 2) in the chart's frame (texel units, x right, y down),
 * the edges d_i = p_{i+1} - p_i (np.roll), twice the signed area, and per edge the
 * function a x + b y + c (positive inside) with c raised by its largest gain over a texel
 * square, (|dx| + |dy|) / 2, times (1 + 1e-7): >= 0 at a texel centre <=> the closed
 * triangle meets the texel.  Returns 0 when the area is not finite (numpy's `usable`
 * is false: nothing marked), else 1 with the edge functions and the box of texels. */
static int edge_functions(const double p[3][2], double a[3], double b[3], double c[3],
                          double box[4])
{
    double d[3][2];
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 2; ++j)
            d[i][j] = p[(i + 1) % 3][j] - p[i][j];
    const double twice_area = d[0][0] * d[2][1] - d[0][1] * d[2][0];
    if (!isfinite(twice_area))
        return 0;
    const double sign = twice_area > 0 ? -1.0 : 1.0;  /* d2 = -(p2 - p0): flip */
    for (int i = 0; i < 3; ++i) {
        a[i] = -sign * d[i][1];
        b[i] = sign * d[i][0];
        c[i] = sign * (d[i][1] * p[i][0] - d[i][0] * p[i][1]);
        c[i] = c[i] + 0.5 * (fabs(d[i][0]) + fabs(d[i][1])) * (1.0 + 1e-7);
    }
    for (int j = 0; j < 2; ++j) {  /* floor of the smallest and largest x (j = 0), y (1) */
        double lo = p[0][j], hi = p[0][j];
        for (int i = 1; i < 3; ++i) {
            lo = p[i][j] < lo ? p[i][j] : lo;
            hi = p[i][j] > hi ? p[i][j] : hi;
        }
        box[2 * j] = floor(lo);
        box[2 * j + 1] = floor(hi);
    }
    return 1;
}

/* chart_marks(xy, faces, face_chart, mask_offset, size, padding, out_covered, out_padded):
 * packing._chart_masks from the frame coordinates on.  xy (m, 2) float64: each vertex in
 * its chart's frame; faces (f, 3) int64; face_chart (f,) int64; chart c's mask has
 * size[c] = (columns, rows) ((k, 2) int64) and sits at mask_offset[c] ((k + 1,) int64) in
 * the flat outputs (uint8 0/1): out_covered the texels its triangles meet, out_padded
 * those grown by `padding` rings.  A triangle whose texels would leave its chart's mask
 * (never, for masks sized as _chart_masks sizes them) is refused with ValueError. */
PyObject *chart_marks(PyObject *self, PyObject *args)
{
    Py_buffer bxy, bf, bfc, boff, bsize, bcov, bpad;
    Py_ssize_t padding;
    PyObject *result = NULL;
    uint8_t *tmp = NULL;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*nw*w*", &bxy, &bf, &bfc, &boff, &bsize, &padding,
                          &bcov, &bpad))
        return NULL;
    {
        const Py_ssize_t m = bxy.len / 16, f = bfc.len / 8, k = bsize.len / 16;
        const Py_ssize_t total = bcov.len;
        if (check(&bxy, "xy", 8, 2 * m) || check(&bf, "faces", 8, 3 * f) ||
            check(&bfc, "face_chart", 8, f) || check(&bsize, "size", 8, 2 * k) ||
            check(&boff, "mask_offset", 8, k + 1) ||
            check(&bcov, "out_covered", 1, total) || check(&bpad, "out_padded", 1, total))
            goto done;
        if (padding < 0) {
            PyErr_SetString(PyExc_ValueError, "chart_marks: padding must be >= 0");
            goto done;
        }
        const double *xy = bxy.buf;
        const int64_t *faces = bf.buf, *fc = bfc.buf, *off = boff.buf, *size = bsize.buf;
        uint8_t *cov = bcov.buf, *pad = bpad.buf;
        if (check_offsets(off, size, k, total, "chart_marks"))
            goto done;
        for (Py_ssize_t t = 0; t < 3 * f; ++t)
            if (faces[t] < 0 || faces[t] >= m) {
                PyErr_Format(PyExc_ValueError, "chart_marks: faces index vertices outside 0..%zd",
                             m - 1);
                goto done;
            }
        for (Py_ssize_t t = 0; t < f; ++t)
            if (fc[t] < 0 || fc[t] >= k) {
                PyErr_Format(PyExc_ValueError, "chart_marks: face %zd's chart is not in 0..%zd",
                             t, k - 1);
                goto done;
            }
        int64_t largest = 0;
        for (Py_ssize_t c = 0; c < k; ++c)
            largest = off[c + 1] - off[c] > largest ? off[c + 1] - off[c] : largest;
        Py_ssize_t outside = -1;
        int no_memory = 0;
        Py_BEGIN_ALLOW_THREADS
        memset(cov, 0, (size_t)total);
        for (Py_ssize_t t = 0; t < f && outside < 0; ++t) {
            double p[3][2], a[3], b[3], c[3], box[4];
            for (int i = 0; i < 3; ++i)
                for (int j = 0; j < 2; ++j)
                    p[i][j] = xy[2 * faces[3 * t + i] + j];
            if (!edge_functions(p, a, b, c, box))
                continue;
            const int64_t *s = size + 2 * fc[t];
            /* compared as doubles before any conversion: a box outside is refused */
            if (!(box[0] >= 0 && box[1] < (double)s[0] && box[2] >= 0 && box[3] < (double)s[1])) {
                outside = t;
                break;
            }
            const int64_t c0 = (int64_t)box[0], c1 = (int64_t)box[1];
            const int64_t r0 = (int64_t)box[2], r1 = (int64_t)box[3];
            uint8_t *mask = cov + off[fc[t]];
            for (int64_t row = r0; row <= r1; ++row) {
                const double cy = (double)row + 0.5;  /* texel centres at (i + 0.5) */
                /* b y, the same product numpy forms; then (a x + b y) + c in its order */
                const double by0 = b[0] * cy, by1 = b[1] * cy, by2 = b[2] * cy;
                uint8_t *out = mask + row * s[0];
                for (int64_t col = c0; col <= c1; ++col) {
                    const double cx = (double)col + 0.5;
                    out[col] |= (uint8_t)((a[0] * cx + by0 + c[0] >= 0) & (a[1] * cx + by1 + c[1] >= 0) &
                                          (a[2] * cx + by2 + c[2] >= 0));
                }
            }
        }
        if (outside < 0) {
            tmp = largest > 0 ? malloc((size_t)largest) : NULL;
            if (largest > 0 && tmp == NULL)
                no_memory = 1;
            else
                for (Py_ssize_t ch = 0; ch < k; ++ch)
                    grow(cov + off[ch], size[2 * ch + 1], size[2 * ch], padding, tmp, pad + off[ch]);
        }
        Py_END_ALLOW_THREADS
        if (outside >= 0) {
            PyErr_Format(PyExc_ValueError, "chart_marks: triangle %zd's texels leave its chart's mask",
                         outside);
            goto done;
        }
        if (no_memory) {
            PyErr_NoMemory();
            goto done;
        }
    }
    Py_INCREF(Py_None);
    result = Py_None;

done:
    free(tmp);
    PyBuffer_Release(&bxy); PyBuffer_Release(&bf); PyBuffer_Release(&bfc);
    PyBuffer_Release(&boff); PyBuffer_Release(&bsize); PyBuffer_Release(&bcov);
    PyBuffer_Release(&bpad);
    return result;
}

/* ---- the packer (packing._Packer, packing._pack_in_order) ----------------------------- */

typedef struct {
    Py_ssize_t width, height;
    int cap, run, rows;     /* HOLE_CAP, HOLE_RUN, HOLE_ROWS */
    uint8_t *occupied;      /* (height, width) */
    int32_t *sky;           /* (width,) each column's lowest occupied row + 1 (0: empty) */
    int16_t *free_run;      /* (height + cap, width) free cells to the right, <= run; the
                               rows past the bottom: 0 */
    int16_t *square;        /* (height, width) side of the largest free square with its
                               top-left corner here, <= cap; NULL until the first hole query */
    int16_t *row_best;      /* (height,) largest square per row (with square) */
    int32_t *scratch;       /* (width,) the skyline's drops, the exhaustive search's runs */
    int32_t *count;         /* (width,) the exhaustive search's rows with room */
} Packer;

/* One quarter turn of a chart's mask (np.rot90(mask, k)) as the skyline sees it: its
 * shape and column profile (packing._profiles): the marked columns, their first and
 * one-past-last marked rows.  The turned mask itself is made only for the turn placed. */
typedef struct {
    Py_ssize_t h, w;
    int32_t *cols;          /* (n_marked,) the marked columns, ascending */
    int32_t *top, *bottom;  /* (n_marked,) */
    int32_t *by_top;        /* (n_marked,) indices into cols, by ascending top */
    Py_ssize_t n_marked;
    double mean_bottom;     /* bottom.mean() over the marked columns, as numpy: sum / count */
} Turn;

/* The profiles of the four turns of an (h, w) mask from its rows' and columns' first
 * and last marked texels, in one pass over it.  np.rot90(m, k)[i, j] is m[i, j] (k = 0),
 * m[j, w-1-i] (1), m[h-1-i, w-1-j] (2), m[h-1-j, i] (3): so column j of turn 1 is row j
 * of m read backwards, of turn 2 column w-1-j upside down, of turn 3 row h-1-j.
 * scratch: 2 (h + w) int32 (the first and last texels), tally: max(h, w) + 1. */
static void profiles(const uint8_t *m, Py_ssize_t h, Py_ssize_t w, int32_t *scratch,
                     Py_ssize_t *tally, Turn turns[4])
{
    int32_t *rfirst = scratch, *rlast = scratch + h, *cfirst = scratch + 2 * h;
    int32_t *clast = cfirst + w;
    for (Py_ssize_t i = 0; i < h; ++i)
        rfirst[i] = rlast[i] = -1;
    for (Py_ssize_t j = 0; j < w; ++j)
        cfirst[j] = clast[j] = -1;
    for (Py_ssize_t i = 0; i < h; ++i) {
        const uint8_t *row = m + i * w;
        for (Py_ssize_t j = 0; j < w; ++j)
            if (row[j]) {
                if (rfirst[i] < 0)
                    rfirst[i] = (int32_t)j;
                rlast[i] = (int32_t)j;
                if (cfirst[j] < 0)
                    cfirst[j] = (int32_t)i;
                clast[j] = (int32_t)i;
            }
    }
    for (int k = 0; k < 4; ++k) {
        Turn *t = &turns[k];
        t->h = (k & 1) ? w : h;
        t->w = (k & 1) ? h : w;
        int64_t sum = 0;
        t->n_marked = 0;
        for (Py_ssize_t j = 0; j < t->w; ++j) {
            int32_t first, last;  /* the turn's column j: first and last marked row, or -1 */
            switch (k) {
            case 0: first = cfirst[j]; last = clast[j]; break;
            case 1: first = rlast[j] < 0 ? -1 : (int32_t)(w - 1 - rlast[j]);
                    last = (int32_t)(w - 1 - rfirst[j]); break;
            case 2: first = clast[w - 1 - j] < 0 ? -1 : (int32_t)(h - 1 - clast[w - 1 - j]);
                    last = (int32_t)(h - 1 - cfirst[w - 1 - j]); break;
            default: first = rfirst[h - 1 - j]; last = rlast[h - 1 - j]; break;
            }
            if (first < 0)
                continue;  /* an unmarked column constrains nothing */
            t->cols[t->n_marked] = (int32_t)j;
            t->top[t->n_marked] = first;
            t->bottom[t->n_marked] = last + 1;
            sum += last + 1;
            t->n_marked++;
        }
        /* exact: the sum of rows is an integer far below 2^53, as numpy's float64 sum */
        t->mean_bottom = t->n_marked ? (double)sum / (double)t->n_marked : 0.0;
        /* the columns by ascending top (a counting sort, stable; it only orders the
         * skyline's tests, never changes a result) */
        Py_ssize_t *start = tally;
        for (Py_ssize_t r = 0; r <= t->h; ++r)
            start[r] = 0;
        for (Py_ssize_t a = 0; a < t->n_marked; ++a)
            start[t->top[a] + 1]++;
        for (Py_ssize_t r = 1; r <= t->h; ++r)
            start[r] += start[r - 1];
        for (Py_ssize_t a = 0; a < t->n_marked; ++a)
            t->by_top[start[t->top[a]]++] = (int32_t)a;
    }
}

/* np.rot90(m, k) of an (h, w) mask into `out` (rows down, counter-clockwise as displayed). */
static void rotate(const uint8_t *m, Py_ssize_t h, Py_ssize_t w, int k, uint8_t *out)
{
    const Py_ssize_t H = (k & 1) ? w : h, W = (k & 1) ? h : w;
    for (Py_ssize_t i = 0; i < H; ++i) {
        uint8_t *o = out + i * W;
        switch (k) {
        case 0: memcpy(o, m + i * w, (size_t)w); break;
        case 1: for (Py_ssize_t j = 0; j < W; ++j) o[j] = m[j * w + (w - 1 - i)]; break;
        case 2: for (Py_ssize_t j = 0; j < W; ++j) o[j] = m[(h - 1 - i) * w + (w - 1 - j)]; break;
        default: for (Py_ssize_t j = 0; j < W; ++j) o[j] = m[(h - 1 - j) * w + i]; break;
        }
    }
}

/* _Packer.skyline: the lowest drop of the turn onto the skyline, the first of equals
 * (np.argmin); 0 when the turn is wider than the strip.  A window's drop is the largest
 * of sky - top over its marked columns (and 0); its columns are tried highest-reaching
 * first and a window is left as soon as its drop reaches the lowest so far: it can no
 * longer be a first strict minimum, so the answer is the full argmin's. */
static int skyline(const Packer *p, const Turn *t, double *score, Py_ssize_t *y, Py_ssize_t *x)
{
    if (t->w > p->width)
        return 0;
    const Py_ssize_t n = p->width - t->w + 1;
    int32_t best = INT32_MAX;
    Py_ssize_t at = 0;
    for (Py_ssize_t i = 0; i < n && best > 0; ++i) {
        const int32_t *sky = p->sky + i;
        int32_t drop = 0;  /* np.maximum(..., 0) */
        Py_ssize_t j = 0;
        for (; j < t->n_marked; ++j) {
            const int32_t c = t->by_top[j], v = sky[t->cols[c]] - t->top[c];
            drop = v > drop ? v : drop;
            if (drop >= best)
                break;
        }
        if (j == t->n_marked) {  /* all columns seen: below every earlier window */
            best = drop;
            at = i;
        }
    }
    *score = (double)best + t->mean_bottom;
    *y = best;
    *x = at;
    return 1;
}

/* _Packer._squares: refresh the free squares with corners in [y0, y1) x [x0, x1) (side =
 * min over rows dy < cap of max(dy, free run there), and at most what it was), then those
 * rows' best.  Rows dy at or past the largest square in the range change nothing
 * (max(dy, .) >= dy), so each row stops there: packed rows, all small squares, are cheap. */
static void squares(Packer *p, Py_ssize_t y0, Py_ssize_t y1, Py_ssize_t x0, Py_ssize_t x1)
{
    const Py_ssize_t W = p->width;
    for (Py_ssize_t cy = y0; cy < y1; ++cy) {
        int16_t *sq = p->square + cy * W;
        int16_t largest = 0;
        for (Py_ssize_t cx = x0; cx < x1; ++cx)
            largest = sq[cx] > largest ? sq[cx] : largest;
        const int depth = largest < p->cap ? largest : p->cap;
        for (int dy = 0; dy < depth; ++dy) {
            const int16_t *fr = p->free_run + (cy + dy) * W;
            const int16_t d = (int16_t)dy;
            for (Py_ssize_t cx = x0; cx < x1; ++cx) {
                const int16_t v = fr[cx] > d ? fr[cx] : d;
                sq[cx] = v < sq[cx] ? v : sq[cx];
            }
        }
        int16_t best = sq[0];
        for (Py_ssize_t cx = 1; cx < W; ++cx)
            best = sq[cx] > best ? sq[cx] : best;
        p->row_best[cy] = best;
    }
}

/* _Packer.hole: the first free h x w box (raster order over the first `rows` rows with a
 * free square of the short side) scoring below `beat`.  1: found, 0: none, -1: no memory. */
static int hole(Packer *p, Py_ssize_t h, Py_ssize_t w, double mean_bottom, double beat,
                double *score, Py_ssize_t *oy, Py_ssize_t *ox)
{
    const Py_ssize_t side = h < w ? h : w, W = p->width;
    if (side > p->cap || w > p->run || w > W)
        return 0;
    Py_ssize_t last = p->height - h;
    if (isfinite(beat)) {
        const double bound = ceil(beat - mean_bottom) - 1.0;  /* int(math.ceil(...)) - 1 */
        if (bound < 0.0)
            return 0;
        if (bound < (double)last)
            last = (Py_ssize_t)bound;
    }
    if (last < 0)
        return 0;
    if (p->square == NULL) {  /* made at the first query that gets this far, as numpy */
        p->square = malloc(sizeof(int16_t) * (size_t)(p->height * W));
        p->row_best = malloc(sizeof(int16_t) * (size_t)p->height);
        if (p->square == NULL || p->row_best == NULL)
            return -1;
        for (Py_ssize_t i = 0; i < p->height * W; ++i)
            p->square[i] = (int16_t)p->cap;
        squares(p, 0, p->height, 0, W);
    }
    int tried = 0;
    for (Py_ssize_t y = 0; y <= last && tried < p->rows; ++y) {
        if (p->row_best[y] < side)
            continue;
        ++tried;
        const int16_t *sq = p->square + y * W;
        for (Py_ssize_t x = 0; x <= W - w; ++x) {
            if (sq[x] < side)
                continue;
            Py_ssize_t d = 0;
            while (d < h && p->free_run[(y + d) * W + x] >= w)
                ++d;
            if (d == h) {
                *score = (double)y + mean_bottom;
                *oy = y;
                *ox = x;
                return 1;
            }
        }
    }
    return 0;
}

/* _Packer.anywhere: the first free h x w box in the strip, raster order.  Rows are scanned
 * down, counting per column the rows in a row with a free run >= w from there: the first
 * row where a count reaches h ends the first box, and its first such column is numpy's. */
static int anywhere(Packer *p, Py_ssize_t h, Py_ssize_t w, Py_ssize_t *oy, Py_ssize_t *ox)
{
    const Py_ssize_t W = p->width;
    if (h > p->height || w > W)
        return 0;
    int32_t *run = p->scratch, *count = p->count;
    for (Py_ssize_t x = 0; x <= W - w; ++x)
        count[x] = 0;
    for (Py_ssize_t r = 0; r < p->height; ++r) {
        const uint8_t *occ = p->occupied + r * W;
        int32_t next = 0;
        for (Py_ssize_t x = W - 1; x >= 0; --x) {
            next = occ[x] ? 0 : next + 1;
            run[x] = next;
        }
        for (Py_ssize_t x = 0; x <= W - w; ++x) {
            count[x] = run[x] >= w ? count[x] + 1 : 0;
            if (count[x] >= h) {
                *oy = r - h + 1;
                *ox = x;
                return 1;
            }
        }
    }
    return 0;
}

/* _Packer.place: mark the turn's texels at (y, x), raise the skyline under its marked
 * columns, cut the free runs that now stop at its texels (up to `run` columns to the left)
 * and, once squares exist, refresh those with corners up to `cap` above or left. */
static void place(Packer *p, const Turn *t, const uint8_t *turned, Py_ssize_t y, Py_ssize_t x)
{
    const Py_ssize_t W = p->width, h = t->h, w = t->w;
    for (Py_ssize_t r = 0; r < h; ++r) {
        uint8_t *occ = p->occupied + (y + r) * W + x;
        const uint8_t *m = turned + r * w;
        for (Py_ssize_t c = 0; c < w; ++c)
            occ[c] |= m[c];
    }
    for (Py_ssize_t j = 0; j < t->n_marked; ++j) {
        int32_t *s = p->sky + x + t->cols[j];
        const int32_t b = (int32_t)y + t->bottom[j];
        *s = b > *s ? b : *s;
    }
    const Py_ssize_t x0 = x - p->run > 0 ? x - p->run : 0;
    for (Py_ssize_t r = 0; r < h; ++r) {
        int16_t *fr = p->free_run + (y + r) * W;
        const uint8_t *m = turned + r * w;
        Py_ssize_t next = x + w + p->run;  /* no texel to the right in the box: no cut */
        for (Py_ssize_t c = x + w - 1; c >= x; --c) {
            if (m[c - x])
                next = c;
            const Py_ssize_t v = next - c < p->run ? next - c : p->run;
            if (v < fr[c])
                fr[c] = (int16_t)v;
        }
        /* left of the box `next` is fixed: the cut min(next - c, run) only reaches the
         * columns with next - c < run (no free run exceeds run) */
        const Py_ssize_t lo = next - p->run + 1 > x0 ? next - p->run + 1 : x0;
        for (Py_ssize_t c = x - 1; c >= lo; --c) {
            const int16_t v = (int16_t)(next - c);
            fr[c] = v < fr[c] ? v : fr[c];
        }
    }
    if (p->square != NULL)
        squares(p, y - p->cap > 0 ? y - p->cap : 0, y + h, x - p->cap > 0 ? x - p->cap : 0, x + w);
}

/* pack_charts(masks, offsets, shapes, order, width, height, upright, hole_cap, hole_run,
 * hole_rows, max_searches, out_place[, state]) -> (fits, placed, used):
 * packing._pack_in_order.
 * masks: the padded masks, flat uint8 (0/1), mask c at offsets[c] ((k + 1,) int64) with
 * shape shapes[c] = (rows, columns) ((k, 2) int64); order (n,) int64 chart indices;
 * out_place (k, 3) int64: per chart (row, column, quarter turns as np.rot90), (0, 0, 0)
 * for charts without texels.  placed: the padded texels placed; used: the strip rows used
 * (`height` when a chart found no room: fits is then False and out_place is partial).
 * state (for tests): None, or writable (occupied uint8 (H, W), sky int32 (W,), free_run
 * int16 (H + cap, W), square int16 (H, W), row_best int16 (H,)) that receive the packer's
 * final state, as packing._Packer's (square and row_best all -1 while not made). */
PyObject *pack_charts(PyObject *self, PyObject *args)
{
    Py_buffer bm, boff, bshape, border, bout, bst[5];
    Py_ssize_t width, height;
    int upright, cap, run, rows, max_searches, with_state = 0;
    PyObject *result = NULL, *state = Py_None;
    (void)self;
    if (!PyArg_ParseTuple(args, "y*y*y*y*nnpiiiiw*|O", &bm, &boff, &bshape, &border, &width,
                          &height, &upright, &cap, &run, &rows, &max_searches, &bout, &state))
        return NULL;
    Packer p = {0};
    uint8_t *turn_buf = NULL;
    int32_t *profile_buf = NULL;
    Py_ssize_t *tally = NULL;
    {
        const Py_ssize_t k = bshape.len / 16, n = border.len / 8;
        if (check(&bm, "masks", 1, bm.len) || check(&bshape, "shapes", 8, 2 * k) ||
            check(&boff, "offsets", 8, k + 1) || check(&border, "order", 8, n) ||
            check(&bout, "out_place", 8, 3 * k))
            goto done;
        if (width < 1 || height < 1 || cap < 1 || run < 1 || rows < 0 || cap > INT16_MAX ||
            run > INT16_MAX || width > PY_SSIZE_T_MAX / 4 / (height + cap)) {
            PyErr_SetString(PyExc_ValueError, "pack_charts: bad strip size or constants");
            goto done;
        }
        if (state != Py_None) {
            if (!PyTuple_Check(state)) {
                PyErr_SetString(PyExc_TypeError, "pack_charts: state must be None or a tuple");
                goto done;
            }
            if (!PyArg_ParseTuple(state, "w*w*w*w*w*", &bst[0], &bst[1], &bst[2], &bst[3], &bst[4]))
                goto done;
            with_state = 1;
            if (check(&bst[0], "occupied", 1, height * width) ||
                check(&bst[1], "sky", 4, width) ||
                check(&bst[2], "free_run", 2, (height + cap) * width) ||
                check(&bst[3], "square", 2, height * width) ||
                check(&bst[4], "row_best", 2, height))
                goto done;
        }
        const uint8_t *masks = bm.buf;
        const int64_t *off = boff.buf, *shape = bshape.buf, *order = border.buf;
        int64_t *out = bout.buf;
        if (check_offsets(off, shape, k, bm.len, "pack_charts"))
            goto done;
        int64_t largest = 0, longest = 0;
        for (Py_ssize_t i = 0; i < n; ++i) {
            if (order[i] < 0 || order[i] >= k) {
                PyErr_Format(PyExc_ValueError, "pack_charts: order[%zd] is not a chart", i);
                goto done;
            }
            const int64_t c = order[i];
            if (off[c + 1] - off[c] > largest)
                largest = off[c + 1] - off[c];
            for (int d = 0; d < 2; ++d)
                if (shape[2 * c + d] > longest)
                    longest = shape[2 * c + d];
        }
        int no_memory = 0, fits = 1;
        int64_t placed = 0, used = height;
        Py_BEGIN_ALLOW_THREADS
        const Py_ssize_t W = width, H = height;
        p.width = W; p.height = H; p.cap = cap; p.run = run; p.rows = rows;
        p.occupied = calloc((size_t)(H * W), 1);
        p.sky = calloc((size_t)W, sizeof(int32_t));
        p.free_run = calloc((size_t)((H + cap) * W), sizeof(int16_t));
        p.scratch = malloc(sizeof(int32_t) * (size_t)W);
        p.count = malloc(sizeof(int32_t) * (size_t)W);
        turn_buf = malloc((size_t)(largest + 1));
        profile_buf = malloc(sizeof(int32_t) * (size_t)(20 * longest + 1));
        tally = malloc(sizeof(Py_ssize_t) * (size_t)(longest + 1));
        if (!p.occupied || !p.sky || !p.free_run || !p.scratch || !p.count || !turn_buf ||
            !profile_buf || !tally)
            no_memory = 1;
        else {
            for (Py_ssize_t x = 0; x < W; ++x)  /* min(width - column, run) */
                p.free_run[x] = (int16_t)(W - x < run ? W - x : run);
            for (Py_ssize_t y = 1; y < H; ++y)
                memcpy(p.free_run + y * W, p.free_run, sizeof(int16_t) * (size_t)W);
            memset(out, 0, sizeof(int64_t) * (size_t)(3 * k));
            Turn turns[4];
            for (int t = 0; t < 4; ++t) {
                turns[t].cols = profile_buf + (4 * t) * longest;
                turns[t].top = profile_buf + (4 * t + 1) * longest;
                turns[t].bottom = profile_buf + (4 * t + 2) * longest;
                turns[t].by_top = profile_buf + (4 * t + 3) * longest;
            }
            int32_t *edges = profile_buf + 16 * longest;  /* 4 longest: rows' and columns' ends */
            int searches = 0;
            for (Py_ssize_t i = 0; i < n && fits && !no_memory; ++i) {
                const int64_t c = order[i];
                const uint8_t *m = masks + off[c];
                const Py_ssize_t h = shape[2 * c], w = shape[2 * c + 1];
                int64_t texels = 0;
                for (Py_ssize_t j = 0; j < h * w; ++j)
                    texels += m[j] != 0;
                if (texels == 0)
                    continue;  /* no texels: its UVs can sit anywhere (see _layout) */
                int allowed[4];
                profiles(m, h, w, edges, tally, turns);
                for (int t = 0; t < 4; ++t)
                    allowed[t] = !upright || turns[t].h >= turns[t].w;
                /* turns k and k + 2 share a box: holes and the exhaustive search try 0, 1 */
                const int boxes[2] = {allowed[0] || allowed[2], allowed[1] || allowed[3]};
                int have = 0, best_k = 0;
                double best = 0.0, score;
                Py_ssize_t best_y = 0, best_x = 0, y, x;
                for (int t = 0; t < 4; ++t)
                    if (allowed[t] && skyline(&p, &turns[t], &score, &y, &x) &&
                        y + turns[t].h <= H && (!have || score < best)) {
                        have = 1; best = score; best_y = y; best_x = x; best_k = t;
                    }
                for (int t = 0; t < 2; ++t) {
                    if (!boxes[t])
                        continue;
                    const int got = hole(&p, turns[t].h, turns[t].w, turns[t].mean_bottom,
                                         have ? best : INFINITY, &score, &y, &x);
                    if (got < 0) {
                        no_memory = 1;
                        break;
                    }
                    if (got && (!have || score < best)) {
                        have = 1; best = score; best_y = y; best_x = x; best_k = t;
                    }
                }
                if (no_memory)
                    break;
                if (!have) {  /* no room on the skyline or in the holes tried */
                    ++searches;
                    for (int t = 0; t < 2 && searches <= max_searches; ++t) {
                        if (!boxes[t] || !anywhere(&p, turns[t].h, turns[t].w, &y, &x))
                            continue;
                        score = (double)y + turns[t].mean_bottom;
                        if (!have || score < best) {
                            have = 1; best = score; best_y = y; best_x = x; best_k = t;
                        }
                    }
                    if (!have) {
                        fits = 0;
                        break;
                    }
                }
                rotate(m, h, w, best_k, turn_buf);
                place(&p, &turns[best_k], turn_buf, best_y, best_x);
                out[3 * c] = best_y; out[3 * c + 1] = best_x; out[3 * c + 2] = best_k;
                placed += texels;
            }
            if (fits && !no_memory) {
                int32_t top = 0;
                for (Py_ssize_t x = 0; x < W; ++x)
                    top = p.sky[x] > top ? p.sky[x] : top;
                used = top;
            }
            if (with_state && !no_memory) {
                memcpy(bst[0].buf, p.occupied, (size_t)(H * W));
                memcpy(bst[1].buf, p.sky, sizeof(int32_t) * (size_t)W);
                memcpy(bst[2].buf, p.free_run, sizeof(int16_t) * (size_t)((H + cap) * W));
                if (p.square != NULL) {
                    memcpy(bst[3].buf, p.square, sizeof(int16_t) * (size_t)(H * W));
                    memcpy(bst[4].buf, p.row_best, sizeof(int16_t) * (size_t)H);
                } else {
                    memset(bst[3].buf, 0xFF, sizeof(int16_t) * (size_t)(H * W));  /* -1 */
                    memset(bst[4].buf, 0xFF, sizeof(int16_t) * (size_t)H);
                }
            }
        }
        Py_END_ALLOW_THREADS
        if (no_memory) {
            PyErr_NoMemory();
            goto done;
        }
        result = Py_BuildValue("(OLL)", fits ? Py_True : Py_False, (long long)placed,
                               (long long)used);
    }

done:
    free(p.occupied); free(p.sky); free(p.free_run); free(p.square); free(p.row_best);
    free(p.scratch); free(p.count); free(turn_buf); free(profile_buf); free(tally);
    PyBuffer_Release(&bm); PyBuffer_Release(&boff); PyBuffer_Release(&bshape);
    PyBuffer_Release(&border); PyBuffer_Release(&bout);
    for (int i = 0; i < 5 && with_state; ++i)
        PyBuffer_Release(&bst[i]);
    return result;
}
