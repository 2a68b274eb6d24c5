/* MCAP records in one pass: laid out for the writer (the native path of
 * layout.lay_out_records) and found in a chunk for the reader (of fastmcap.parse_records).
 *
 * records(out, starts, channel, log_time, publish_time, group, row, payloads, counters) writes record
 * i at out[starts[i]:]: opcode 0x05, record length (uint64), channel id (uint16), sequence (uint32),
 * log time and publish time (log_time[i], publish_time[i]: uint64), then row row[i] of payloads[group[i]]
 * (a C-contiguous 2-D uint8 array: one payload per row).  The sequence number of a record is
 * ++counters[channel[i]] (an int64 array indexed by channel id, updated in place), so each channel
 * counts on by itself.  All integers are little-endian, as MCAP wants.  The index arrays must be
 * C-contiguous, aligned int64 (numpy's); out and counters may share no memory with any other
 * argument.  The indices are copied into this call's own memory and every one checked before a byte
 * is written; a bad one raises ValueError and leaves out and counters untouched.  The copy runs
 * without the interpreter lock.
 *
 * scan(data, starts, others) walks the records of a decompressed chunk: the start of every message
 * record goes into starts (int64, at least len(data) // 31 + 1 long: a message record has 31 bytes
 * or more), of every schema and channel record into others (int64, len(data) // 23 + 1); a record of
 * another opcode is skipped (the MCAP spec's rule for records it does not know).  Returns (message
 * count, schema/channel count): memory does not grow with the records' number.  A record that runs
 * past the end of data, a message, schema or channel record shorter than its fields, or an
 * opcode-0 record raises ValueError.  The three buffers must not overlap.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#define OP_SCHEMA 0x03
#define OP_CHANNEL 0x04
#define OP_MESSAGE 0x05
#define HEAD_BYTES 31   /* opcode 1 + length 8 + channel 2 + sequence 4 + log time 8 + publish time 8 */
#define FIXED_BYTES 22  /* the record's length counts everything after the opcode and length */
#define SCHEMA_FIXED 14  /* id 2 + name length 4 + encoding length 4 + data length 4 */
#define CHANNEL_FIXED 16  /* id 2 + schema id 2 + topic length 4 + encoding length 4 + metadata length 4 */
#define MIN_OTHER_BYTES (9 + SCHEMA_FIXED)

/* whether two buffers share a byte */
static int ranges_overlap(const Py_buffer *a, const Py_buffer *b) {
    const char *a0 = a->buf, *b0 = b->buf;
    return a->len > 0 && b->len > 0 && a0 < b0 + b->len && b0 < a0 + a->len;
}

static void put_le(uint8_t *p, uint64_t v, int n) {
    for (int k = 0; k < n; k++) {
        p[k] = (uint8_t)(v >> (8 * k));
    }
}

/* whether a buffer format is one signed 64-bit integer (numpy's int64: "q", or "l" where long is 64 bits) */
static int is_int64_format(const char *format) {
    if (format == NULL) return 0;
    if (*format == '<' || *format == '=' || *format == '@') format++;
    return (format[0] == 'q' || (format[0] == 'l' && sizeof(long) == 8)) && format[1] == '\0';
}

/* a C-contiguous, 8-byte-aligned 1-D buffer of n int64 (n < 0: any number), or -1 with an exception set */
static int get_int64(PyObject *obj, Py_buffer *view, Py_ssize_t n, const char *name, int writable) {
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0)) < 0) {
        return -1;
    }
    if (view->itemsize != 8 || !is_int64_format(view->format) || view->len % 8 != 0
            || (n >= 0 && view->len / 8 != n)) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd int64 values", name, n);
        PyBuffer_Release(view);
        return -1;
    }
    if (((uintptr_t)view->buf) % 8 != 0) {
        PyErr_Format(PyExc_ValueError, "%s: not aligned to 8 bytes", name);
        PyBuffer_Release(view);
        return -1;
    }
    return 0;
}

static PyObject *records(PyObject *self, PyObject *args) {
    (void)self;
    PyObject *out_o, *starts_o, *channel_o, *time_o, *publish_o, *group_o, *row_o, *payloads_o, *counters_o;
    if (!PyArg_ParseTuple(args, "OOOOOOOOO:records", &out_o, &starts_o, &channel_o, &time_o, &publish_o,
                          &group_o, &row_o, &payloads_o, &counters_o)) {
        return NULL;
    }
    PyObject *seq = PySequence_Fast(payloads_o, "payloads: expected a sequence of 2-D uint8 arrays");
    if (seq == NULL) {
        return NULL;
    }
    Py_ssize_t n_groups = PySequence_Fast_GET_SIZE(seq);
    /* one group per payload width: a handful for replay, as many as an imported bag's widths */
    Py_buffer *payload = PyMem_Calloc(n_groups > 0 ? (size_t)n_groups : 1, sizeof(Py_buffer));
    if (payload == NULL) {
        Py_DECREF(seq);
        return PyErr_NoMemory();
    }
    Py_buffer out = {0}, starts = {0}, channel = {0}, ltime = {0}, ptime = {0}, group = {0}, row = {0},
              counters = {0};
    Py_ssize_t got_payloads = 0;
    PyObject *result = NULL;
    int64_t *private = NULL;
    Py_ssize_t n = -1;
    if (PyObject_GetBuffer(out_o, &out, PyBUF_C_CONTIGUOUS | PyBUF_WRITABLE) < 0) goto done_out;
    if (get_int64(starts_o, &starts, -1, "starts", 0) < 0) goto done_starts;
    n = starts.len / 8;
    if (get_int64(channel_o, &channel, n, "channel", 0) < 0) goto done_channel;
    if (get_int64(time_o, &ltime, n, "log_time", 0) < 0) goto done_time;
    if (get_int64(publish_o, &ptime, n, "publish_time", 0) < 0) goto done_publish;
    if (get_int64(group_o, &group, n, "group", 0) < 0) goto done_group;
    if (get_int64(row_o, &row, n, "row", 0) < 0) goto done_row;
    if (get_int64(counters_o, &counters, -1, "counters", 1) < 0) goto done_counters;
    for (; got_payloads < n_groups; got_payloads++) {
        Py_buffer *v = &payload[got_payloads];
        if (PyObject_GetBuffer(PySequence_Fast_GET_ITEM(seq, got_payloads), v,
                               PyBUF_C_CONTIGUOUS | PyBUF_ND) < 0) goto done_payloads;
        if (v->ndim != 2 || v->itemsize != 1) {
            PyBuffer_Release(v);
            PyErr_Format(PyExc_ValueError, "payloads[%zd]: expected a 2-D uint8 array", got_payloads);
            goto done_payloads;
        }
    }
    {
        /* out and counters are written: neither may share a byte with another buffer (a view of
         * starts as out, counters as channel: the writes would change the indices being used) */
        const Py_buffer *inputs[] = {&starts, &channel, &ltime, &ptime, &group, &row, &counters};
        for (int k = 0; k < 7; k++) {
            if (ranges_overlap(&out, inputs[k]) || (k < 6 && ranges_overlap(&counters, inputs[k]))) {
                PyErr_SetString(PyExc_ValueError, "out and counters must not share memory with another argument");
                goto done_payloads;
            }
        }
        for (Py_ssize_t k = 0; k < got_payloads; k++) {
            if (ranges_overlap(&out, &payload[k]) || ranges_overlap(&counters, &payload[k])) {
                PyErr_SetString(PyExc_ValueError, "out and counters must not share memory with a payload array");
                goto done_payloads;
            }
        }
        /* the indices copied into memory of this call's own before they are checked: another thread
         * cannot change them between the check and their use without the interpreter lock */
        private = PyMem_Malloc(n > 0 ? (size_t)n * 6 * sizeof(int64_t) : 1);
        if (private == NULL) {
            PyErr_NoMemory();
            goto done_payloads;
        }
        memcpy(private, starts.buf, (size_t)n * sizeof(int64_t));
        memcpy(private + n, channel.buf, (size_t)n * sizeof(int64_t));
        memcpy(private + 2 * n, ltime.buf, (size_t)n * sizeof(int64_t));
        memcpy(private + 3 * n, group.buf, (size_t)n * sizeof(int64_t));
        memcpy(private + 4 * n, row.buf, (size_t)n * sizeof(int64_t));
        memcpy(private + 5 * n, ptime.buf, (size_t)n * sizeof(int64_t));
        const int64_t *st = private, *ch = private + n, *lt = private + 2 * n, *gr = private + 3 * n,
                      *rw = private + 4 * n, *pt = private + 5 * n;
        int64_t *count = counters.buf;
        const Py_ssize_t n_channels = counters.len / 8;
        uint8_t *dst = out.buf;
        /* every index checked first: a bad call writes nothing */
        for (Py_ssize_t i = 0; i < n; i++) {
            if (gr[i] < 0 || gr[i] >= n_groups) {
                PyErr_Format(PyExc_ValueError, "group[%zd] = %lld: no such payload array", i, (long long)gr[i]);
                goto done_payloads;
            }
            const Py_buffer *v = &payload[gr[i]];
            if (rw[i] < 0 || rw[i] >= v->shape[0]) {
                PyErr_Format(PyExc_ValueError, "row[%zd] = %lld: beyond its payload array", i, (long long)rw[i]);
                goto done_payloads;
            }
            if (ch[i] < 0 || ch[i] >= n_channels || ch[i] > 0xFFFF) {
                PyErr_Format(PyExc_ValueError, "channel[%zd] = %lld: no counter", i, (long long)ch[i]);
                goto done_payloads;
            }
            if (st[i] < 0 || st[i] > out.len - HEAD_BYTES - v->shape[1]) {
                PyErr_Format(PyExc_ValueError, "starts[%zd] = %lld: the record ends beyond out", i, (long long)st[i]);
                goto done_payloads;
            }
        }
        Py_BEGIN_ALLOW_THREADS
        for (Py_ssize_t i = 0; i < n; i++) {
            const Py_buffer *v = &payload[gr[i]];
            const Py_ssize_t width = v->shape[1];
            uint8_t *p = dst + st[i];
            const int64_t sequence = ++count[ch[i]];
            p[0] = OP_MESSAGE;
            put_le(p + 1, (uint64_t)(FIXED_BYTES + width), 8);
            put_le(p + 9, (uint64_t)ch[i], 2);
            put_le(p + 11, (uint64_t)sequence & 0xFFFFFFFFu, 4);
            put_le(p + 15, (uint64_t)lt[i], 8);
            put_le(p + 23, (uint64_t)pt[i], 8);
            memcpy(p + HEAD_BYTES, (const uint8_t *)v->buf + rw[i] * width, (size_t)width);
        }
        Py_END_ALLOW_THREADS
    }
    result = Py_None;
    Py_INCREF(result);
done_payloads:
    PyMem_Free(private);
    for (Py_ssize_t k = 0; k < got_payloads; k++) PyBuffer_Release(&payload[k]);
    PyBuffer_Release(&counters);
done_counters:
    PyBuffer_Release(&row);
done_row:
    PyBuffer_Release(&group);
done_group:
    PyBuffer_Release(&ptime);
done_publish:
    PyBuffer_Release(&ltime);
done_time:
    PyBuffer_Release(&channel);
done_channel:
    PyBuffer_Release(&starts);
done_starts:
    PyBuffer_Release(&out);
done_out:
    PyMem_Free(payload);
    Py_DECREF(seq);
    return result;
}

static PyObject *scan(PyObject *self, PyObject *args) {
    PyObject *data_o, *starts_o, *others_o;
    (void)self;
    if (!PyArg_ParseTuple(args, "OOO:scan", &data_o, &starts_o, &others_o)) {
        return NULL;
    }
    Py_buffer data = {0}, starts = {0}, others = {0};
    PyObject *result = NULL;
    if (PyObject_GetBuffer(data_o, &data, PyBUF_C_CONTIGUOUS) < 0) return NULL;
    if (get_int64(starts_o, &starts, -1, "starts", 1) < 0) goto done_data;
    if (get_int64(others_o, &others, -1, "others", 1) < 0) goto done_starts;
    if (starts.len / 8 < data.len / HEAD_BYTES + 1 || others.len / 8 < data.len / MIN_OTHER_BYTES + 1) {
        PyErr_SetString(PyExc_ValueError, "starts / others: shorter than len(data) // 31 + 1 / len(data) // 23 + 1");
        goto done_others;
    }
    if (ranges_overlap(&data, &starts) || ranges_overlap(&data, &others) || ranges_overlap(&starts, &others)) {
        PyErr_SetString(PyExc_ValueError, "data, starts and others must not share memory");
        goto done_others;
    }
    {
        const uint8_t *buf = data.buf;
        const uint64_t n = (uint64_t)data.len;
        int64_t *st = starts.buf, *ot = others.buf;
        Py_ssize_t count = 0, n_others = 0;
        uint64_t pos = 0;
        const char *problem = NULL;
        while (pos + 9 <= n) {
            const uint8_t op = buf[pos];
            uint64_t length = 0;
            for (int k = 7; k >= 0; k--) length = (length << 8) | buf[pos + 1 + k];
            if (length > n - pos - 9) {
                problem = "record runs past the end of its chunk";
                break;
            }
            if (op == OP_MESSAGE) {
                if (length < FIXED_BYTES) {
                    problem = "message record shorter than a message's fields";
                    break;
                }
                st[count++] = (int64_t)pos;
            } else if (op == OP_SCHEMA || op == OP_CHANNEL) {
                if (length < (op == OP_SCHEMA ? SCHEMA_FIXED : CHANNEL_FIXED)) {
                    problem = "schema or channel record shorter than its fields";
                    break;
                }
                ot[n_others++] = (int64_t)pos;
            } else if (op == 0) {
                problem = "invalid record (opcode 0)";
                break;
            } /* any other opcode: a record a later MCAP version may add, skipped (the spec's rule) */
            pos += 9 + length;
        }
        if (problem != NULL) {
            PyErr_SetString(PyExc_ValueError, problem);
            goto done_others;
        }
        result = Py_BuildValue("(nn)", count, n_others);
    }
done_others:
    PyBuffer_Release(&others);
done_starts:
    PyBuffer_Release(&starts);
done_data:
    PyBuffer_Release(&data);
    return result;
}

static PyMethodDef methods[] = {
    {"records", records, METH_VARARGS,
     "records(out, starts, channel, log_time, publish_time, group, row, payloads, counters): lay out MCAP "
     "message records."},
    {"scan", scan, METH_VARARGS, "scan(data, starts, others) -> (message count, schema/channel count): a chunk's records."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_records", "MCAP records laid out and found in one pass.", -1, methods,
    NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__records(void) { return PyModule_Create(&module); }
