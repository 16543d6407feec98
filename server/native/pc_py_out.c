/* The way out: the shown pose's passes, upper_body and hinge (pc_upper.c), and the
 * protocol v2 delta records, encode_deltas (pc_records.c). Plain scalar C, one pose or
 * record at a time on the calling thread (no levels, no pool); the arrays and the
 * tables the kernels index by (limbs, parents) are checked with the GIL held.
 */
#include "pc_module.h"

#include <stdint.h>
#include <string.h>

#include "pc_records.h"
#include "pc_upper.h"

/* --- the shown pose's passes ------------------------------------------------------- */

/* The shown poses' positions (E, 19, 3) float32 in b; E, or -1 with the error set. */
static Py_ssize_t get_poses(PyObject *o, PcBuf *b) {
    if (pc_get_buf(o, b, "positions", F32, -1, 0)) return -1;
    Py_ssize_t E = b->view.len / 4 / 57;
    if (E * 57 * 4 != b->view.len) {
        PyErr_SetString(PyExc_ValueError, "positions: not (E, 19, 3)");
        return -1;
    }
    return E;
}

static PyObject *py_upper_body(PyObject *self, PyObject *args) {
    PyObject *o[9], *free_obj;
    PcUpperArgs a;
    if (!PyArg_ParseTuple(args, "OOOOOdddddOOOO", &o[0], &o[1], &o[2], &o[3], &free_obj, &a.wrist_share,
                          &a.lean_share, &a.neck_share, &a.spine_reach, &a.reach_tol, &o[4], &o[5], &o[6],
                          &o[7]))
        return NULL;
    PcBuf b[9];
    memset(b, 0, sizeof(b));
    Py_ssize_t E = get_poses(o[0], &b[0]);
    if (E < 0) goto fail;
    if (pc_get_buf(o[1], &b[1], "rotations", F32, E * 76, 0) ||
        pc_get_buf(o[2], &b[2], "tracker_pos", F64, -1, 0))
        goto fail;
    a.slots = E ? b[2].view.len / 8 / 3 / E : 3;
    if (a.slots < 3 || a.slots * 3 * E * 8 != b[2].view.len) {
        PyErr_SetString(PyExc_ValueError, "tracker_pos: not (E, slots >= 3, 3)");
        goto fail;
    }
    if (pc_get_buf(o[3], &b[3], "tracker_quat", F64, E * a.slots * 4, 0) ||
        (free_obj != Py_None && pc_get_buf(free_obj, &b[8], "free_root", BOOL, E, 0)) ||
        pc_get_buf(o[4], &b[4], "offsets", F64, 57, 0) ||
        pc_get_buf(o[5], &b[5], "positions_out", F32, E * 57, 1) ||
        pc_get_buf(o[6], &b[6], "rotations_out", F32, E * 76, 1) ||
        pc_get_buf(o[7], &b[7], "reach_limited", BOOL, E, 1))
        goto fail;
    a.pos_in = b[0].view.buf;
    a.quat_in = b[1].view.buf;
    a.tp = b[2].view.buf;
    a.tq = b[3].view.buf;
    a.free = free_obj != Py_None ? b[8].view.buf : NULL;
    a.offsets = b[4].view.buf;
    a.pos_out = b[5].view.buf;
    a.quat_out = b[6].view.buf;
    a.limited = b[7].view.buf;
    Py_BEGIN_ALLOW_THREADS;
    pc_upper_rows(&a, 0, E);
    Py_END_ALLOW_THREADS;
    pc_release(b, 9);
    Py_RETURN_NONE;
fail:
    pc_release(b, 9);
    return NULL;
}

static PyObject *py_hinge(PyObject *self, PyObject *args) {
    PyObject *o[3];
    PcHingeArgs h;
    if (!PyArg_ParseTuple(args, "OOOdddd", &o[0], &o[1], &o[2], &h.straight, &h.span, &h.flip, &h.flip_span))
        return NULL;
    PcBuf b[3];
    memset(b, 0, sizeof(b));
    Py_ssize_t E = get_poses(o[0], &b[0]);
    if (E < 0) goto fail;
    if (pc_get_buf(o[1], &b[1], "rotations", F32, E * 76, 1) ||
        pc_get_buf(o[2], &b[2], "limbs", F64, -1, 0))
        goto fail;
    h.limbs = b[2].view.len / 8 / 9;
    if (h.limbs * 9 * 8 != b[2].view.len) {
        PyErr_SetString(PyExc_ValueError, "limbs: not (L, 9)");
        goto fail;
    }
    /* A copy, checked while the GIL is held: joints in 0..18, and no joint turned by two
     * limbs (the C turns limb by limb; the reference reads every limb before writing). */
    if (h.limbs > PC_MAX_LIMBS) {
        PyErr_Format(PyExc_ValueError, "limbs: at most %d", PC_MAX_LIMBS);
        goto fail;
    }
    double spec[PC_MAX_LIMBS * 9];
    memcpy(spec, b[2].view.buf, (size_t)h.limbs * 9 * sizeof(double));
    int used[19] = {0};
    for (Py_ssize_t l = 0; l < h.limbs; l++)
        for (int k = 0; k < 3; k++) {
            double j = spec[9 * l + k];
            if (!(j >= 0 && j < 19 && j == (int)j)) {
                PyErr_SetString(PyExc_ValueError, "limbs: joints outside 0..18");
                goto fail;
            }
            if (k < 2 && used[(int)j]++) {
                PyErr_SetString(PyExc_ValueError, "limbs: a joint in two limbs");
                goto fail;
            }
        }
    h.pos = b[0].view.buf;
    h.quat = b[1].view.buf;
    h.spec = spec;
    Py_BEGIN_ALLOW_THREADS;
    pc_hinge_rows(&h, 0, E);
    Py_END_ALLOW_THREADS;
    pc_release(b, 3);
    Py_RETURN_NONE;
fail:
    pc_release(b, 3);
    return NULL;
}

/* --- v2 delta records ------------------------------------------------------------- */

static PyObject *py_encode_deltas(PyObject *self, PyObject *args) {
    PyObject *o[14];
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &o[8], &o[9], &o[10], &o[11], &o[12], &o[13]))
        return NULL;
    PcBuf b[14];
    memset(b, 0, sizeof(b));
    PcDeltaArgs a;
    if (pc_get_buf(o[0], &b[0], "parents", I64, PC_REC_ITEMS, 0) || pc_get_buf(o[1], &b[1], "seq", I64, -1, 0))
        goto fail;
    Py_ssize_t M = b[1].view.len / 8;
    if (pc_get_buf(o[2], &b[2], "ref_seq", I64, M, 0) || pc_get_buf(o[3], &b[3], "flags", I64, M, 0) ||
        pc_get_buf(o[4], &b[4], "ref_items", F64, M * PC_REC_ITEMS * 4, 0) ||
        pc_get_buf(o[5], &b[5], "step_rot", I64, M * PC_REC_ITEMS * 3, 0) ||
        pc_get_buf(o[6], &b[6], "world", F64, M * PC_REC_ITEMS * 4, 0) ||
        pc_get_buf(o[7], &b[7], "ref_root", I64, M * 3, 0) ||
        pc_get_buf(o[8], &b[8], "step_root", I64, M * 3, 0) ||
        pc_get_buf(o[9], &b[9], "root", I64, M * 3, 0) ||
        pc_get_buf(o[10], &b[10], "new_items", F64, M * PC_REC_ITEMS * 4, 1) ||
        pc_get_buf(o[11], &b[11], "d_rot", I64, M * PC_REC_ITEMS * 3, 1) ||
        pc_get_buf(o[12], &b[12], "body", "B", 1, M * PC_REC_MAX_BYTES, 1) ||
        pc_get_buf(o[13], &b[13], "len", I64, M, 1))
        goto fail;
    /* Parents before children, checked while the GIL is held. */
    int64_t parents[PC_REC_ITEMS];
    memcpy(parents, b[0].view.buf, sizeof(parents));
    for (int j = 0; j < PC_REC_ITEMS; j++)
        if (!(j == 0 ? parents[j] == -1 : parents[j] >= 0 && parents[j] < j)) {
            PyErr_SetString(PyExc_ValueError, "parents: not a tree in joint order");
            goto fail;
        }
    a.m = M;
    a.parents = parents;
    a.seq = b[1].view.buf;
    a.ref_seq = b[2].view.buf;
    a.flags = b[3].view.buf;
    a.ref_items = b[4].view.buf;
    a.step_rot = b[5].view.buf;
    a.world = b[6].view.buf;
    a.ref_root = b[7].view.buf;
    a.step_root = b[8].view.buf;
    a.root = b[9].view.buf;
    a.new_items = b[10].view.buf;
    a.d_rot = b[11].view.buf;
    a.body = b[12].view.buf;
    a.len = b[13].view.buf;
    Py_BEGIN_ALLOW_THREADS;
    pc_encode_deltas(&a);
    Py_END_ALLOW_THREADS;
    pc_release(b, 14);
    Py_RETURN_NONE;
fail:
    pc_release(b, 14);
    return NULL;
}

PyMethodDef pc_out_methods[] = {
    {"upper_body", py_upper_body, METH_VARARGS, "Head and hands onto their trackers (upper_ik)."},
    {"hinge", py_hinge, METH_VARARGS, "Limbs onto their hinges, in place (hinge)."},
    {"encode_deltas", py_encode_deltas, METH_VARARGS, "Protocol v2 delta records (records.encode_deltas)."},
    {NULL, NULL, 0, NULL},
};
