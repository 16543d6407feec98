/* The shown pose's passes in C (pc_upper.c): ports of upper_ik.solve_upper_body and
 * hinge._hinge. */
#ifndef PC_UPPER_H
#define PC_UPPER_H

#include <stdint.h>

typedef struct {
    const float *pos_in;  /* (E, 19, 3) world positions */
    const float *quat_in; /* (E, 19, 4) world rotations, xyzw */
    const double *tp;     /* (E, slots, 3) trackers, slot order */
    const double *tq;     /* (E, slots, 4) their rotations, xyzw */
    int64_t slots;
    const uint8_t *free;  /* (E,) the pelvis is a guess, or NULL: none is */
    double wrist_share, lean_share, neck_share, spine_reach, reach_tol;
    const double *offsets; /* (19, 3) reference bone offsets */
    float *pos_out;        /* (E, 19, 3) */
    float *quat_out;       /* (E, 19, 4) */
    uint8_t *limited;      /* (E,) */
} PcUpperArgs;

void pc_upper_rows(const PcUpperArgs *a, int64_t r0, int64_t r1);

/* The hinges (hinge._hinge): per pose, each limb (upper, lower, end joint, the hinge
 * axis and the flexed direction in the upper joint's frame: 9 doubles) onto its hinge;
 * the upper and lower joints' rotations change in place. No joint may be the upper or
 * lower joint of two limbs (the binding checks). */
#define PC_MAX_LIMBS 8

typedef struct {
    const float *pos; /* (E, 19, 3) */
    float *quat;      /* (E, 19, 4) in place */
    const double *spec;
    int64_t limbs;
    double straight, span, flip, flip_span;
} PcHingeArgs;

void pc_hinge_rows(const PcHingeArgs *h, int64_t r0, int64_t r1);

#endif
