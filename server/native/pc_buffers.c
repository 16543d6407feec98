/* Arrays in through the buffer protocol (numpy arrays, no numpy headers), checked for
 * layout, dtype and length before a kernel sees them. */
#include "pc_module.h"

#include <string.h>

int pc_get_buf(PyObject *obj, PcBuf *b, const char *what, const char *formats, Py_ssize_t itemsize,
               Py_ssize_t count, int writable) {
    b->held = 0;
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) != 0) {
        PyErr_Format(PyExc_ValueError, "%s: needs a C-contiguous%s array", what,
                     writable ? " writable" : "");
        return -1;
    }
    b->held = 1;
    const char *fmt = b->view.format ? b->view.format : "B";
    if (*fmt == '<' || *fmt == '=' || *fmt == '@') fmt++;
    if (b->view.itemsize != itemsize || strlen(fmt) != 1 || !strchr(formats, fmt[0])) {
        PyErr_Format(PyExc_ValueError, "%s: wrong dtype (format %s, itemsize %zd)", what, fmt,
                     b->view.itemsize);
        return -1;
    }
    if (count >= 0 && b->view.len != count * itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd items, got %zd", what, count,
                     b->view.len / itemsize);
        return -1;
    }
    return 0;
}

void pc_release(PcBuf *bufs, int n) {
    for (int i = 0; i < n; i++)
        if (bufs[i].held) PyBuffer_Release(&bufs[i].view);
}
