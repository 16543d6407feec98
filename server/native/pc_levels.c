/* The instruction-set levels: the one dispatch point of the SSI kernels.
 *
 * The same kernels (pc_impl.h) are compiled once per level, each in its own file
 * under its own target pragma (pc_isa_*.c), so one build runs on any x86-64. At import
 * the best level this CPU supports is chosen, avx512bf16 -> avx512f -> avx2 (with FMA)
 * -> generic, capped by POSECAST_NATIVE_ISA; set_isa changes it (the Python side's
 * self-check steps down a level that disagrees with generic). The GRU gates'
 * precision is a setting of its own: bf16 by default on avx512bf16, fp32 elsewhere,
 * unless POSECAST_NATIVE_PRECISION or set_precision names one. See docs/engine.md.
 */
#include "pc_module.h"

#include <stdlib.h>
#include <string.h>

typedef struct {
    const char *name;
    const PcKernels *k;
    int (*supported)(void);
} Level;

#if defined(__x86_64__) || defined(_M_X64)
static int has_avx512bf16(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512bf16");
}
static int has_avx512(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
}
static int has_avx2(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#endif
static int always(void) { return 1; }

static const Level LEVELS[] = {
#if defined(__x86_64__) || defined(_M_X64)
    {"avx512bf16", &pc_kernels_avx512bf16, has_avx512bf16},
    {"avx512f", &pc_kernels_avx512, has_avx512},
    {"avx2", &pc_kernels_avx2, has_avx2},
#endif
    {"generic", &pc_kernels_generic, always},
};
#define N_LEVELS ((int)(sizeof(LEVELS) / sizeof(LEVELS[0])))

static int g_level = N_LEVELS - 1;
/* The GRU gates' arithmetic, separate from the level: 1 bf16 (on the level's
 * instructions where it has them, avx512bf16, else the same arithmetic in plain vector
 * code), 0 fp32. */
static int g_bf16 = 0;

const PcKernels *pc_level_kernels(void) { return LEVELS[g_level].k; }

int pc_bf16_gates(void) { return g_bf16; }

static int level_index(const char *name) {
    for (int i = 0; i < N_LEVELS; i++)
        if (strcmp(LEVELS[i].name, name) == 0) return i;
    return -1;
}

/* The best supported level at or below `cap` (an index; 0 is the best). */
static int best_level(int cap) {
    for (int i = cap; i < N_LEVELS; i++)
        if (LEVELS[i].supported()) return i;
    return N_LEVELS - 1;
}

int pc_levels_init(void) {
    /* The best level the CPU runs, capped by POSECAST_NATIVE_ISA; bf16 gates where that
     * level has the bf16 instructions, fp32 elsewhere, unless POSECAST_NATIVE_PRECISION
     * names one (bf16 on a level without the instructions: the same arithmetic in plain
     * vector code). The bf16 figures on the validation split: docs/engine.md. */
    int cap = 0;
    const char *forced = getenv("POSECAST_NATIVE_ISA");
    if (forced && *forced) {
        cap = level_index(forced);
        if (cap < 0) {
            PyErr_Format(PyExc_ImportError,
                         "POSECAST_NATIVE_ISA=%s is not one of avx512bf16, avx512f, avx2, generic", forced);
            return -1;
        }
    }
    g_level = best_level(cap);
    g_bf16 = strcmp(LEVELS[g_level].name, "avx512bf16") == 0;
    const char *prec = getenv("POSECAST_NATIVE_PRECISION");
    if (prec && *prec) {
        if (strcmp(prec, "bf16") != 0 && strcmp(prec, "fp32") != 0) {
            PyErr_Format(PyExc_ImportError, "POSECAST_NATIVE_PRECISION=%s is not one of bf16, fp32", prec);
            return -1;
        }
        g_bf16 = strcmp(prec, "bf16") == 0;
    }
    return 0;
}

/* --- the Python functions ------------------------------------------------------------ */

static PyObject *py_isa(PyObject *self, PyObject *noargs) { return PyUnicode_FromString(LEVELS[g_level].name); }

static PyObject *py_isas(PyObject *self, PyObject *noargs) {
    PyObject *out = PyList_New(0);
    for (int i = 0; out && i < N_LEVELS; i++)
        if (LEVELS[i].supported()) {
            PyObject *s = PyUnicode_FromString(LEVELS[i].name);
            if (!s || PyList_Append(out, s) != 0) {
                Py_XDECREF(s);
                Py_DECREF(out);
                return NULL;
            }
            Py_DECREF(s);
        }
    if (!out) return NULL;
    PyObject *t = PyList_AsTuple(out);
    Py_DECREF(out);
    return t;
}

static PyObject *py_set_isa(PyObject *self, PyObject *arg) {
    const char *name = PyUnicode_AsUTF8(arg);
    if (!name) return NULL;
    int i = level_index(name);
    if (i < 0) return PyErr_Format(PyExc_ValueError, "unknown ISA level %s", name);
    if (!LEVELS[i].supported()) return PyErr_Format(PyExc_ValueError, "this CPU cannot run %s", name);
    g_level = i;
    Py_RETURN_NONE;
}

static PyObject *py_precision(PyObject *self, PyObject *noargs) {
    return PyUnicode_FromString(g_bf16 ? "bf16" : "fp32");
}

static PyObject *py_set_precision(PyObject *self, PyObject *arg) {
    const char *name = PyUnicode_AsUTF8(arg);
    if (!name) return NULL;
    if (strcmp(name, "bf16") != 0 && strcmp(name, "fp32") != 0)
        return PyErr_Format(PyExc_ValueError, "unknown precision %s (bf16 or fp32)", name);
    g_bf16 = strcmp(name, "bf16") == 0;
    Py_RETURN_NONE;
}

PyMethodDef pc_levels_methods[] = {
    {"isa", py_isa, METH_NOARGS, "The instruction-set level in use."},
    {"isas", py_isas, METH_NOARGS, "Levels this CPU runs, best first."},
    {"set_isa", py_set_isa, METH_O, "Use this level (one from isas())."},
    {"precision", py_precision, METH_NOARGS, "The GRU gates' arithmetic: bf16 or fp32."},
    {"set_precision", py_set_precision, METH_O, "bf16 or fp32 gates, on any level."},
    {NULL, NULL, 0, NULL},
};
