/* The per-record byte work of a live read, compiled: checking wire records and laying
 * out their ImuSample messages with the CRC-32 each is sealed with.
 *
 * Every rule applied here comes in as data worked out in Python from the command
 * table and the message layout (bridge.protocol.codec.native_checks,
 * bridge.bus.codec.native_layout): no record layout, bound or field number is
 * written in this file. Where this module is not built, the pure-Python paths give
 * the very same answers and bytes (tests/test_native.py).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <stdint.h>
#include <string.h>

static uint32_t crc_table[256];

static void crc_init(void) {
    for (uint32_t n = 0; n < 256; n++) {
        uint32_t c = n;
        for (int k = 0; k < 8; k++) c = c & 1 ? 0xEDB88320u ^ (c >> 1) : c >> 1;
        crc_table[n] = c;
    }
}

/* IEEE 802.3 CRC-32, as zlib.crc32 */
static uint32_t crc32_of(const uint8_t *p, Py_ssize_t n) {
    uint32_t c = 0xFFFFFFFFu;
    while (n--) c = crc_table[(c ^ *p++) & 0xFF] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

static double wire_value(const uint8_t *p, int width, int is_float, int little) {
    uint32_t v = 0;
    for (int b = 0; b < width; b++) v |= (uint32_t)p[little ? b : width - 1 - b] << (8 * b);
    if (is_float) {
        float f;
        memcpy(&f, &v, 4);
        return (double)f;
    }
    return (double)v;
}

/* checks: doubles, per check: offset, count, width, is_float, little_endian, lo, hi,
 * n_values, then n_values allowed values (lo/hi: -inf/+inf when unbounded). A float
 * outside lo..hi passes when it is not finite: a unit sends NaN and infinities. */
static int record_ok(const uint8_t *rec, Py_ssize_t size, int code, const double *checks,
                     Py_ssize_t n_checks) {
    if (rec[0] != code) return 0;
    uint32_t sum = 0;
    for (Py_ssize_t i = 0; i < size - 2; i++) sum += rec[i];
    if ((sum & 0xFFFF) != ((uint32_t)rec[size - 2] << 8 | rec[size - 1])) return 0;
    Py_ssize_t at = 0;
    while (at < n_checks) {
        const double *c = checks + at;
        int offset = (int)c[0], count = (int)c[1], width = (int)c[2];
        int is_float = (int)c[3], little = (int)c[4];
        double lo = c[5], hi = c[6];
        int n_values = (int)c[7];
        const double *values = c + 8;
        for (int k = 0; k < count; k++) {
            double v = wire_value(rec + offset + width * k, width, is_float, little);
            if (!(lo <= v && v <= hi) && (!is_float || isfinite(v))) return 0;
            if (n_values) {
                int found = 0;
                for (int j = 0; j < n_values; j++) found |= values[j] == v;
                if (!found) return 0;
            }
        }
        at += 8 + n_values;
    }
    return 1;
}

/* Whether every check reads whole values inside a record of ``size`` bytes. */
static int checks_fit(const double *checks, Py_ssize_t n_checks, Py_ssize_t size) {
    Py_ssize_t at = 0;
    while (at < n_checks) {
        if (n_checks - at < 8) return 0;
        const double *c = checks + at;
        double offset = c[0], count = c[1], width = c[2], n_values = c[7];
        if (!(offset >= 1 && count >= 1 && (width == 1 || width == 2 || width == 4)
              && offset + count * width <= size - 2 && n_values >= 0
              && n_values <= (double)(n_checks - at - 8)))
            return 0;
        if (c[3] != 0 && width != 4) return 0;  /* floats are float32 */
        at += 8 + (Py_ssize_t)n_values;
    }
    return 1;
}

PyDoc_STRVAR(intact_doc,
"intact(buf, start, size, code, limit, checks) -> int\n\n"
"How many records of ``size`` bytes from ``start`` in ``buf``, at most ``limit``, in a\n"
"row start with ``code``, match their checksum and pass ``checks``.");

static PyObject *intact(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 6) {
        PyErr_SetString(PyExc_TypeError, "intact() takes 6 arguments");
        return NULL;
    }
    Py_ssize_t start = PyLong_AsSsize_t(args[1]), size = PyLong_AsSsize_t(args[2]);
    long code = PyLong_AsLong(args[3]);
    Py_ssize_t limit = PyLong_AsSsize_t(args[4]);
    if (PyErr_Occurred()) return NULL;
    Py_buffer buf, checks;
    if (PyObject_GetBuffer(args[0], &buf, PyBUF_SIMPLE) < 0) return NULL;
    if (PyObject_GetBuffer(args[5], &checks, PyBUF_SIMPLE) < 0) {
        PyBuffer_Release(&buf);
        return NULL;
    }
    Py_ssize_t good = 0;
    if (size < 3 || start < 0 || !checks_fit((const double *)checks.buf,
                                             checks.len / (Py_ssize_t)sizeof(double), size)
        || checks.len % sizeof(double)) {
        PyErr_SetString(PyExc_ValueError, "intact(): bad size, start or checks");
    } else {
        const uint8_t *p = (const uint8_t *)buf.buf;
        Py_ssize_t n_checks = checks.len / (Py_ssize_t)sizeof(double);
        while (good < limit && start + (good + 1) * size <= buf.len
               && record_ok(p + start + good * size, size, (int)code,
                            (const double *)checks.buf, n_checks))
            good++;
    }
    PyBuffer_Release(&checks);
    PyBuffer_Release(&buf);
    if (PyErr_Occurred()) return NULL;
    return PyLong_FromSsize_t(good);
}

static void put_le64(uint8_t *p, long long v) {
    uint64_t u = (uint64_t)v;
    for (int b = 0; b < 8; b++) p[b] = (uint8_t)(u >> (8 * b));
}

#define MAX_TIMES 8

PyDoc_STRVAR(messages_doc,
"messages(template, moves, at, wire, times) -> (payloads, seals)\n\n"
"One message per wire record: ``template`` with the record's bytes moved in\n"
"(``moves``: uint16 little-endian pairs, message position then record position) and\n"
"each list of ``times`` (one int per record) written as a little-endian int64 at the\n"
"position ``at`` gives it; each message with its CRC-32 as 4 little-endian bytes.");

static PyObject *messages(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "messages() takes 5 arguments");
        return NULL;
    }
    PyObject *wire = args[3], *times = args[4];
    if (!PyList_Check(wire) || !PyTuple_Check(times) || !PyTuple_Check(args[2])) {
        PyErr_SetString(PyExc_TypeError, "messages(): wire is a list, at and times tuples");
        return NULL;
    }
    Py_ssize_t k_times = PyTuple_GET_SIZE(times);
    if (PyTuple_GET_SIZE(args[2]) != k_times || k_times > MAX_TIMES) {
        PyErr_SetString(PyExc_ValueError, "messages(): a position in at for each of times");
        return NULL;
    }
    Py_ssize_t n = PyList_GET_SIZE(wire);
    PyObject *columns[MAX_TIMES];
    Py_ssize_t at[MAX_TIMES];
    for (Py_ssize_t k = 0; k < k_times; k++) {
        columns[k] = PyTuple_GET_ITEM(times, k);
        if (!PyList_Check(columns[k]) || PyList_GET_SIZE(columns[k]) != n) {
            PyErr_SetString(PyExc_ValueError,
                            "messages(): each of times is a list as long as wire");
            return NULL;
        }
        at[k] = PyLong_AsSsize_t(PyTuple_GET_ITEM(args[2], k));
        if (at[k] == -1 && PyErr_Occurred()) return NULL;
    }
    Py_buffer tpl, moves;
    if (PyObject_GetBuffer(args[0], &tpl, PyBUF_SIMPLE) < 0) return NULL;
    if (PyObject_GetBuffer(args[1], &moves, PyBUF_SIMPLE) < 0) {
        PyBuffer_Release(&tpl);
        return NULL;
    }
    PyObject *payloads = PyList_New(n), *seals = PyList_New(n);
    const uint8_t *mv = (const uint8_t *)moves.buf;
    Py_ssize_t n_moves = moves.len / 4, size = tpl.len;
    Py_ssize_t need = 0;  /* the record bytes the moves read */
    for (Py_ssize_t m = 0; m < n_moves; m++) {
        Py_ssize_t to = mv[4 * m] | mv[4 * m + 1] << 8, from = mv[4 * m + 2] | mv[4 * m + 3] << 8;
        if (to >= size) {
            PyErr_SetString(PyExc_ValueError, "messages(): a move lands outside the message");
            goto fail;
        }
        if (from >= need) need = from + 1;
    }
    for (Py_ssize_t k = 0; k < k_times; k++) {
        if (at[k] < 0 || at[k] + 8 > size) {
            PyErr_SetString(PyExc_ValueError, "messages(): a time lands outside the message");
            goto fail;
        }
    }
    if (payloads == NULL || seals == NULL) goto fail;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *rec = PyList_GET_ITEM(wire, i);
        if (!PyBytes_Check(rec) || PyBytes_GET_SIZE(rec) < need) {
            PyErr_Format(PyExc_ValueError, "messages(): record %zd is not bytes of %zd or more",
                         i, need);
            goto fail;
        }
        long long values[MAX_TIMES];
        for (Py_ssize_t k = 0; k < k_times; k++)
            values[k] = PyLong_AsLongLong(PyList_GET_ITEM(columns[k], i));
        if (PyErr_Occurred()) goto fail;
        PyObject *out = PyBytes_FromStringAndSize(NULL, size);
        if (out == NULL) goto fail;
        uint8_t *o = (uint8_t *)PyBytes_AS_STRING(out);
        const uint8_t *r = (const uint8_t *)PyBytes_AS_STRING(rec);
        memcpy(o, tpl.buf, size);
        for (Py_ssize_t m = 0; m < n_moves; m++)
            o[mv[4 * m] | mv[4 * m + 1] << 8] = r[mv[4 * m + 2] | mv[4 * m + 3] << 8];
        for (Py_ssize_t k = 0; k < k_times; k++) put_le64(o + at[k], values[k]);
        PyList_SET_ITEM(payloads, i, out);
        uint32_t crc = crc32_of(o, size);
        uint8_t le[4] = {(uint8_t)crc, (uint8_t)(crc >> 8), (uint8_t)(crc >> 16),
                         (uint8_t)(crc >> 24)};
        PyObject *seal = PyBytes_FromStringAndSize((const char *)le, 4);
        if (seal == NULL) goto fail;
        PyList_SET_ITEM(seals, i, seal);
    }
    PyBuffer_Release(&moves);
    PyBuffer_Release(&tpl);
    return Py_BuildValue("(NN)", payloads, seals);
fail:
    Py_XDECREF(payloads);
    Py_XDECREF(seals);
    PyBuffer_Release(&moves);
    PyBuffer_Release(&tpl);
    return NULL;
}

static PyMethodDef methods[] = {
    {"intact", (PyCFunction)(void (*)(void))intact, METH_FASTCALL, intact_doc},
    {"messages", (PyCFunction)(void (*)(void))messages, METH_FASTCALL, messages_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "bridge._records",
    "The per-record byte work of a live read, compiled (see bridge/_records.c).", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__records(void) {
    crc_init();
    return PyModule_Create(&module);
}
