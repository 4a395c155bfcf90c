/* aobake._kernels, the OBJ fast reader's two block parsers (aobake.obj._floats and
 * aobake.obj._corners), compiled.
 *
 * Each takes the block of one element kind (its lines, each ending with one line break,
 * as aobake.obj._read_fast_bytes gathers them) and returns what the numpy twin returns,
 * or None where it declines: the caller then runs the numpy twin, which reads the block or
 * declines in turn (and the slow reader then says what is wrong).  So these kernels only
 * have to be right on what they accept, and they accept only the plain forms:
 *
 *   obj_floats: every line "KEY x1 ... xw" with the same w; a value is
 *     [+-] digits [. digits] [(e|E) [+-] digits] (a digit in the mantissa), anything else
 *     (inf, nan, "1_0", a comment) declines.  The value is float()'s: Clinger's exact path
 *     where it applies (at most 19 significant digits forming an integer m <= 2^53, a
 *     decimal exponent e in -22..22: m * 10^e or m / 10^-e is one correctly rounded IEEE
 *     operation on two exact operands, so it is the correctly rounded value), else
 *     Python's own PyOS_string_to_double (float() itself).
 *   obj_corners: every line "f" and corners [-]digits [/ [[-]digits] [/ [-]digits]], an
 *     index of at most 18 characters; bytes other than digits, "-", "/", spaces and tabs
 *     decline.
 * The GIL is held: PyOS_string_to_double may set an exception (cleared: that token declines).
 */
#include "_kernels.h"

#include <string.h>

static inline int is_break(unsigned char c) { return c >= 10 && c <= 13; } /* \n \v \f \r */
static inline int is_space(unsigned char c) { return c == ' ' || c == '\t' || is_break(c); }
static inline int is_digit(unsigned char c) { return c >= '0' && c <= '9'; }

static const double POW10[23] = {1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10,
                                 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19,
                                 1e20, 1e21, 1e22};

/* float() of the token [s, end), or -1 where the token is not of the plain form. */
static int parse_double(const char *s, const char *end, double *out)
{
    const char *p = s;
    int negative = 0;
    if (p < end && (*p == '+' || *p == '-'))
        negative = *p++ == '-';
    uint64_t m = 0;
    int significant = 0, digits = 0, dropped = 0;
    long scale = 0; /* the decimal exponent of m's last digit */
    for (; p < end && is_digit((unsigned char)*p); ++p, ++digits) {
        const int d = *p - '0';
        if (m == 0 && d == 0)
            continue;
        if (significant < 19) {
            m = 10 * m + (uint64_t)d;
            ++significant;
        } else {
            dropped = 1;
            ++scale;
        }
    }
    if (p < end && *p == '.') {
        for (++p; p < end && is_digit((unsigned char)*p); ++p, ++digits) {
            const int d = *p - '0';
            if (m == 0 && d == 0) {
                --scale;
                continue;
            }
            if (significant < 19) {
                m = 10 * m + (uint64_t)d;
                ++significant;
                --scale;
            } else {
                dropped = 1;
            }
        }
    }
    if (!digits)
        return -1;
    long exponent = 0;
    if (p < end && (*p == 'e' || *p == 'E')) {
        ++p;
        int minus = 0;
        if (p < end && (*p == '+' || *p == '-'))
            minus = *p++ == '-';
        if (p == end || !is_digit((unsigned char)*p))
            return -1;
        for (; p < end && is_digit((unsigned char)*p); ++p)
            if (exponent < 100000)
                exponent = 10 * exponent + (*p - '0');
        if (minus)
            exponent = -exponent;
    }
    if (p != end)
        return -1;
    const long e = exponent + scale;
    double value;
    if (m == 0) {
        value = 0.0;
    } else if (!dropped && m <= (UINT64_C(1) << 53) && e >= -22 && e <= 22) {
        value = e >= 0 ? (double)m * POW10[e] : (double)m / POW10[-e];
    } else {
        /* float() itself; the token is followed by whitespace (or the bytes object's NUL) */
        char *stop = NULL;
        value = PyOS_string_to_double(s, &stop, NULL);
        if (value == -1.0 && PyErr_Occurred()) {
            PyErr_Clear();
            return -1;
        }
        if (stop != end)
            return -1;
        *out = value;
        return 0;
    }
    *out = negative ? -value : value;
    return 0;
}

/* obj_floats(block, count, key, least) -> (w, bytearray of count * w float64) | None
 *
 * block: bytes, ``count`` lines "KEY x1 ... xw", each ended by one line break; key: bytes;
 * least: the fewest values a line may have (w >= least).  None where aobake.obj._floats's
 * numpy twin is to decide (see the file's comment).
 */
PyObject *obj_floats(PyObject *self, PyObject *args)
{
    const char *block, *key;
    Py_ssize_t size, key_size, count, least;
    (void)self;
    if (!PyArg_ParseTuple(args, "y#ny#n", &block, &size, &count, &key, &key_size, &least))
        return NULL;
    if (count <= 0)
        Py_RETURN_NONE;
    /* the first line's width sizes the output */
    Py_ssize_t width = -1;
    {
        Py_ssize_t tokens = 0;
        for (Py_ssize_t i = 0; i < size && !is_break((unsigned char)block[i]); ++i)
            if (!is_space((unsigned char)block[i]) &&
                (i == 0 || is_space((unsigned char)block[i - 1])))
                ++tokens;
        width = tokens - 1;
    }
    if (width < least || width < 1)
        Py_RETURN_NONE;
    if ((size_t)count > (size_t)PY_SSIZE_T_MAX / 8 / (size_t)width)
        Py_RETURN_NONE;
    PyObject *values = PyByteArray_FromStringAndSize(NULL, count * width * 8);
    if (values == NULL)
        return NULL;
    double *out = (double *)PyByteArray_AS_STRING(values);
    Py_ssize_t line = 0, column = 0, i = 0;
    int ok = 1;
    while (ok && i < size) {
        const unsigned char c = (unsigned char)block[i];
        if (c >= 128) {
            ok = 0;
        } else if (is_break(c)) {
            /* a line ends: it must have held the key and exactly w values */
            if (column != width + 1)
                ok = 0;
            ++line;
            column = 0;
            ++i;
        } else if (is_space(c)) {
            ++i;
        } else {
            Py_ssize_t j = i;
            while (j < size && !is_space((unsigned char)block[j]))
                ++j;
            if (column == 0) {
                ok = j - i == key_size && memcmp(block + i, key, (size_t)key_size) == 0;
            } else if (column > width || line >= count) {
                ok = 0;
            } else if (parse_double(block + i, block + j, out + line * width + column - 1)) {
                ok = 0;
            }
            ++column;
            i = j;
        }
    }
    if (!ok || line != count || column != 0) {
        Py_DECREF(values);
        Py_RETURN_NONE;
    }
    PyObject *result = Py_BuildValue("nN", width, values);
    return result;
}

/* One index field [-]digits of at most 18 characters in [s, end): 0 and its value, or -1. */
static int parse_index(const char *s, const char *end, int64_t *out)
{
    const char *p = s;
    const int negative = p < end && *p == '-';
    if (end - s > 18)
        return -1;
    p += negative;
    if (p == end)
        return -1;
    int64_t value = 0;
    for (; p < end; ++p) {
        if (!is_digit((unsigned char)*p))
            return -1;
        value = 10 * value + (*p - '0');
    }
    *out = negative ? -value : value;
    return 0;
}

/* obj_corners(block, count) -> (per_face, vertex, texture, normal, has_texture,
 * has_normal) | None
 *
 * block: bytes, ``count`` f lines, each ended by one line break.  per_face: bytearray of
 * count int64 (corners per line); vertex, texture, normal: bytearrays of n int64 (n
 * corners; 0 where absent); has_texture, has_normal: bytearrays of n bool.  None where
 * aobake.obj._corners's numpy twin is to decide.
 */
PyObject *obj_corners(PyObject *self, PyObject *args)
{
    const char *block;
    Py_ssize_t size, count;
    (void)self;
    if (!PyArg_ParseTuple(args, "y#n", &block, &size, &count))
        return NULL;
    /* Pass 1: every line "f", a space or tab, then only digits, "-", "/", spaces and
     * tabs up to its line break; the number of corners.  Branch-free over byte classes
     * (the branches of a byte-by-byte test mispredict at every corner). */
    enum { BAD, BLANK, BREAK, INDEX, EFF };
    static unsigned char kind[256];
    if (!kind['f']) {
        for (int c = '0'; c <= '9'; ++c)
            kind[c] = INDEX;
        kind['-'] = kind['/'] = INDEX;
        kind[' '] = kind['\t'] = BLANK;
        kind['\n'] = kind['\v'] = kind['\f'] = kind['\r'] = BREAK;
        kind['f'] = EFF;
    }
    Py_ssize_t corners = 0, lines = 0;
    int bad = 0;
    unsigned prev = BREAK;
    for (Py_ssize_t i = 0; i < size; ++i) {
        const unsigned c = kind[(unsigned char)block[i]];
        bad |= (c == BAD) | ((c == EFF) != (prev == BREAK)) | ((prev == EFF) & (c != BLANK));
        lines += c == BREAK;
        corners += (c == INDEX) & (prev == BLANK);
        prev = c;
    }
    if (bad || prev != BREAK || lines != count || corners == 0)
        Py_RETURN_NONE; /* no corners at all: numpy's twin declines too */
    PyObject *arrays[6] = {
        PyByteArray_FromStringAndSize(NULL, count * 8),
        PyByteArray_FromStringAndSize(NULL, corners * 8),
        PyByteArray_FromStringAndSize(NULL, corners * 8),
        PyByteArray_FromStringAndSize(NULL, corners * 8),
        PyByteArray_FromStringAndSize(NULL, corners),
        PyByteArray_FromStringAndSize(NULL, corners),
    };
    for (int k = 0; k < 6; ++k)
        if (arrays[k] == NULL) {
            for (int q = 0; q < 6; ++q)
                Py_XDECREF(arrays[q]);
            return NULL;
        }
    int64_t *per_face = (int64_t *)PyByteArray_AS_STRING(arrays[0]);
    int64_t *field_out[3] = {(int64_t *)PyByteArray_AS_STRING(arrays[1]),
                             (int64_t *)PyByteArray_AS_STRING(arrays[2]),
                             (int64_t *)PyByteArray_AS_STRING(arrays[3])};
    char *has[3] = {NULL, PyByteArray_AS_STRING(arrays[4]), PyByteArray_AS_STRING(arrays[5])};
    /* Pass 2: each corner's fields. */
    Py_ssize_t line = 0, corner = 0, on_line = 0, i = 1; /* block[0] is the first "f" */
    int ok = 1;
    while (ok && i < size) {
        const unsigned char c = (unsigned char)block[i];
        if (is_break(c)) {
            per_face[line++] = on_line;
            on_line = 0;
            ++i;
            if (i < size)
                ++i; /* the next line's "f" */
        } else if (is_space(c)) {
            ++i;
        } else {
            Py_ssize_t j = i;
            while (j < size && !is_space((unsigned char)block[j]))
                ++j;
            /* fields between slashes: the vertex, then the texture, then the normal */
            int field = 0;
            Py_ssize_t start = i;
            field_out[1][corner] = field_out[2][corner] = 0;
            has[1][corner] = has[2][corner] = 0;
            for (Py_ssize_t q = i; q <= j && ok; ++q) {
                if (q < j && block[q] != '/')
                    continue;
                if (field > 2) {
                    ok = 0;
                } else if (q > start) {
                    ok = parse_index(block + start, block + q, field_out[field] + corner) == 0;
                    if (field)
                        has[field][corner] = 1;
                } else if (field == 0) {
                    ok = 0; /* a corner without its vertex index ("/2") */
                }
                ++field;
                start = q + 1;
            }
            ++corner;
            ++on_line;
            i = j;
        }
    }
    if (!ok || line != count || corner != corners) {
        for (int q = 0; q < 6; ++q)
            Py_DECREF(arrays[q]);
        Py_RETURN_NONE;
    }
    return Py_BuildValue("NNNNNN", arrays[0], arrays[1], arrays[2], arrays[3], arrays[4],
                         arrays[5]);
}
