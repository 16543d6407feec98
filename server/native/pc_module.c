/* posecast._native: the SSI kernels as a CPython extension.
 *
 * Arrays come in through the buffer protocol (numpy arrays, no numpy headers), the
 * GIL is released while the kernels run, and the work of one call is cut into
 * tiles of PC_TILE rows that the calling thread and the pool's workers take from one
 * atomic counter: one thread pool for the whole tick, nothing else spins.
 *
 * Instruction-set dispatch happens once at import (and on set_isa): the best level
 * this CPU supports among avx512bf16, avx512f, avx2, generic, capped by the
 * environment variable POSECAST_NATIVE_ISA. The GRU gates' precision is a setting of
 * its own (set_precision, POSECAST_NATIVE_PRECISION): bf16 by default on the
 * avx512bf16 level, fp32 on the others. See docs/engine.md.
 *
 * This file is the module itself: the import, and the functions of the other files
 * (pc_module.h lists them) gathered into it.
 */
#include "pc_module.h"

static struct PyModuleDef MODULE = {PyModuleDef_HEAD_INIT, "_native", "posecast's native SSI kernels.", -1,
                                    NULL};

PyMODINIT_FUNC PyInit__native(void) {
    if (pc_levels_init() != 0 || pc_threads_init() != 0) return NULL;
    PyObject *m = PyModule_Create(&MODULE);
    if (!m) return NULL;
    PyMethodDef *tables[] = {pc_levels_methods, pc_threads_methods, pc_pack_methods, pc_ssi_methods,
                             pc_out_methods};
    for (size_t i = 0; i < sizeof(tables) / sizeof(tables[0]); i++)
        if (PyModule_AddFunctions(m, tables[i]) != 0) {
            Py_DECREF(m);
            return NULL;
        }
    return m;
}
