/* AVX-512 with BF16: the GRU gates as bf16 dot products (vdpbf16ps) on fp32 state;
 * the heads, FK, IK and scoring stay fp32 as on the AVX-512F level. */
#if defined(__x86_64__) || defined(_M_X64)
#pragma GCC target("avx512f,avx512dq,avx512bw,avx512vl,avx512bf16,fma")
#define PC_VW 16
#define PC_MR 6
#define PC_NB 4
#include <immintrin.h>
#define PC_SPLAT(x) _mm512_set1_ps(x)
#define PC_RCP(x) _mm512_rcp14_ps((__m512)(x))
#define PC_BF16 1
#define PC_NAME "avx512bf16"
#define PC_TABLE pc_kernels_avx512bf16
#include "pc_impl.h"
#endif
