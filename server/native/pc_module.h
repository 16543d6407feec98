/* posecast._native's Python side: what its files share.
 *
 *   pc_module.c    the module: its import (level, precision, pool) and its functions
 *   pc_levels.c    the instruction-set levels: the one dispatch point, isa, precision
 *   pc_threads.c   the thread pool that runs every kernel call's tiles
 *   pc_buffers.c   arrays in through the buffer protocol, checked
 *   pc_py_pack.c   the weights packed for the kernels: pack_decoder, pack_pool
 *   pc_py_ssi.c    the SSI kernels' calls: decode, pool, emit
 *   pc_py_out.c    the way out: the shown pose's passes (upper_body, hinge) and the
 *                  v2 delta records (encode_deltas)
 *
 * Each file keeps its state and its Python functions to itself and hands the module
 * one method table (pc_*_methods), which pc_module.c adds at import.
 */
#ifndef PC_MODULE_H
#define PC_MODULE_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <stdint.h>

#include "pc_kernels.h"

/* --- levels (pc_levels.c) ---------------------------------------------------------- */

/* The kernels of the level in use, and whether the GRU gates run in bf16. */
const PcKernels *pc_level_kernels(void);
int pc_bf16_gates(void);
/* At import: the level and precision from the CPU and the environment; -1 with
 * ImportError set on an unknown POSECAST_NATIVE_ISA or POSECAST_NATIVE_PRECISION. */
int pc_levels_init(void);

/* --- the thread pool (pc_threads.c) --------------------------------------------------- */

/* One tile's work: rows [r0, r1) with the thread's scratch (PC_SCRATCH_BYTES). */
typedef void (*PcTileFn)(void *ctx, int64_t r0, int64_t r1, float *scratch);
/* Run fn on every tile of PC_TILE rows of `rows`, on the calling thread and the
 * pool's workers; returns when all are done. Call it without the GIL. */
void pc_parallel_rows(PcTileFn fn, void *ctx, int64_t rows);
/* At import: the caller's scratch and the fork handler; -1 with MemoryError set. */
int pc_threads_init(void);

/* --- buffers (pc_buffers.c) ------------------------------------------------------------ */

typedef struct {
    Py_buffer view;
    int held;
} PcBuf;

/* Get a C-contiguous buffer of `count` items of `itemsize` bytes whose format is one
 * of `formats` (struct-module codes); count < 0 accepts any length. -1 with
 * ValueError set, the buffer held or not (pc_release releases what is held). */
int pc_get_buf(PyObject *obj, PcBuf *b, const char *what, const char *formats, Py_ssize_t itemsize,
               Py_ssize_t count, int writable);
void pc_release(PcBuf *bufs, int n);

/* formats, itemsize: the dtypes the kernels take */
#define F32 "f", 4
#define F64 "d", 8
#define I64 "lq", 8
#define BOOL "?B", 1

/* --- packed weights (pc_py_pack.c, read by pc_py_ssi.c) -------------------------------- */

#define PC_DECODER_CAPSULE "posecast.decoder"
#define PC_POOL_CAPSULE "posecast.pool"

typedef struct {
    PcDecoder d;
    void *mem;
} PcDecoderBox;

typedef struct {
    PcPool p;
    void *mem;
} PcPoolBox;

/* --- the method tables --------------------------------------------------------------- */

extern PyMethodDef pc_levels_methods[];
extern PyMethodDef pc_threads_methods[];
extern PyMethodDef pc_pack_methods[];
extern PyMethodDef pc_ssi_methods[];
extern PyMethodDef pc_out_methods[];

#endif
