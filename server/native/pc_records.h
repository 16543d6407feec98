/* Protocol v2 delta records in C (pc_records.c): a port of
 * posecast.online.protocol.records.encode_deltas (the reference, numpy). */
#ifndef PC_RECORDS_H
#define PC_RECORDS_H

#include <stdint.h>

#define PC_REC_ITEMS 19    /* rotation items: PELVIS world, then 18 local rotations */
#define PC_REC_MAX_BYTES 98 /* the longest delta body: flags, seq delta, bitstream */

typedef struct {
    int64_t m;                /* poses */
    const int64_t *parents;   /* (19,) each joint's parent (< the joint), -1 for PELVIS */
    const double *ref_items;  /* (M, 19, 4) what each client holds */
    const int64_t *step_rot;  /* (M, 19, 3) its last rotation steps */
    const double *world;      /* (M, 19, 4) the new poses' world rotations */
    const int64_t *ref_root;  /* (M, 3) 0.1 mm */
    const int64_t *step_root; /* (M, 3) */
    const int64_t *root;      /* (M, 3) the new poses' roots */
    const int64_t *seq;       /* (M,) the new poses' seq */
    const int64_t *ref_seq;   /* (M,) the references' seq */
    const int64_t *flags;     /* (M,) each record's flags byte */
    double *new_items;        /* (M, 19, 4) out: what the client holds after the record */
    int64_t *d_rot;           /* (M, 19, 3) out: the new steps */
    uint8_t *body;            /* (M, PC_REC_MAX_BYTES) out: the bodies, flags onwards */
    int64_t *len;             /* (M,) out: each body's length; 0 where it does not fit */
} PcDeltaArgs;

void pc_encode_deltas(const PcDeltaArgs *a);

#endif
