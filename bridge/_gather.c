/* Reading a port until a record's bytes are all in, compiled: the reads a live bridge
 * makes while a record crosses the line happen here, with the GIL released, and Python
 * wakes once per whole record instead of once per piece the link hands over.
 *
 * Each read keeps its own bytes and receive time, as Python's reads would (the framer
 * and the clock use both): the raw monotonic and the realtime clock, read together. Where this module is not built, bridge.device.port makes
 * one read per call and its caller loops: the same reads, the same records.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <errno.h>
#include <poll.h>
#include <stdint.h>
#include <time.h>
#include <unistd.h>

#define READ_SIZE 65536

#define PAIR_NS 20000 /* as bridge.device.clock.PAIR_NS */
#define PAIR_TRIES 3

static int64_t ns_of(clockid_t clock) {
    struct timespec t;
    clock_gettime(clock, &t);
    return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

/* The raw and realtime clocks read together, as bridge.device.clock.stamp reads them: the
 * realtime clock between two raw readings (again where something came between). */
static void stamp(int64_t *raw, int64_t *real) {
    int64_t best = -1;
    for (int i = 0; i < PAIR_TRIES; i++) {
        int64_t before = ns_of(CLOCK_MONOTONIC_RAW), now = ns_of(CLOCK_REALTIME),
                after = ns_of(CLOCK_MONOTONIC_RAW);
        if (best < 0 || after - before < best) {
            best = after - before;
            *raw = (before + after) >> 1;
            *real = now;
        }
        if (after - before <= PAIR_NS) break;
    }
}

PyDoc_STRVAR(gather_doc,
"gather(fd, need, wait_s) -> (reads, raw_ns, real_ns, gone)\n\n"
"Read the non-blocking ``fd`` as its bytes come until ``need`` bytes have come or\n"
"``wait_s`` has passed: each read's bytes and its receive time on the raw monotonic\n"
"and the realtime clock, read together, and whether the other end was gone (a read of\n"
"no bytes).");

static PyObject *gather(PyObject *self, PyObject *const *args, Py_ssize_t nargs) {
    (void)self;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "gather() takes 3 arguments");
        return NULL;
    }
    int fd = (int)PyLong_AsLong(args[0]);
    Py_ssize_t need = PyLong_AsSsize_t(args[1]);
    double wait_s = PyFloat_AsDouble(args[2]);
    if (PyErr_Occurred()) return NULL;
    if (wait_s < 0) wait_s = 0;
    char *buf = PyMem_Malloc(READ_SIZE);
    PyObject *reads = PyList_New(0), *raws = PyList_New(0), *reals = PyList_New(0);
    if (buf == NULL || reads == NULL || raws == NULL || reals == NULL) {
        PyErr_NoMemory();
        goto fail;
    }
    int64_t deadline = ns_of(CLOCK_MONOTONIC) + (int64_t)(wait_s * 1e9);
    Py_ssize_t got = 0;
    int gone = 0;
    for (;;) {
        int64_t left = deadline - ns_of(CLOCK_MONOTONIC);
        if (left < 0) left = 0;
        struct timespec timeout = {(time_t)(left / 1000000000), (long)(left % 1000000000)};
        struct pollfd p = {fd, POLLIN, 0};
        int ready, err = 0;
        ssize_t n = -1;
        int64_t raw = 0, real = 0;
        Py_BEGIN_ALLOW_THREADS
        ready = ppoll(&p, 1, &timeout, NULL);
        if (ready > 0) {
            n = read(fd, buf, READ_SIZE);
            stamp(&raw, &real);
        }
        err = errno;
        Py_END_ALLOW_THREADS
        if (ready < 0 && err == EINTR) break;  /* a signal: let Python see it */
        if (ready < 0) {
            errno = err;
            PyErr_SetFromErrno(PyExc_OSError);
            goto fail;
        }
        if (ready == 0) break;  /* wait_s passed */
        if (n < 0) {
            if (err == EAGAIN || err == EINTR) {
                if (left == 0) break;
                continue;
            }
            errno = err;
            PyErr_SetFromErrno(PyExc_OSError);
            goto fail;
        }
        if (n == 0) {
            gone = 1;
            break;
        }
        PyObject *data = PyBytes_FromStringAndSize(buf, n), *at_raw = PyLong_FromLongLong(raw),
                 *at_real = PyLong_FromLongLong(real);
        int appended = data != NULL && at_raw != NULL && at_real != NULL
            && PyList_Append(reads, data) == 0 && PyList_Append(raws, at_raw) == 0
            && PyList_Append(reals, at_real) == 0;
        Py_XDECREF(data);
        Py_XDECREF(at_raw);
        Py_XDECREF(at_real);
        if (!appended) goto fail;
        got += n;
        if (got >= need || left == 0) break;
    }
    PyMem_Free(buf);
    return Py_BuildValue("(NNNO)", reads, raws, reals, gone ? Py_True : Py_False);
fail:
    PyMem_Free(buf);
    Py_XDECREF(reads);
    Py_XDECREF(raws);
    Py_XDECREF(reals);
    return NULL;
}

static PyMethodDef methods[] = {
    {"gather", (PyCFunction)(void (*)(void))gather, METH_FASTCALL, gather_doc},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "bridge._gather",
    "Reading a port until a record's bytes are all in (see bridge/_gather.c).", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__gather(void) { return PyModule_Create(&module); }
