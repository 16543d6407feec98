/* The upper-body pass in C: head on the headset, hands on the controllers.
 *
 * A line-for-line port of posecast.body.upper_ik.solve_upper_body (the
 * reference, numpy), one pose at a time in double precision; tests/online/inference/test_native.py parity-tests
 * it against that function. The numpy version costs about 2.5 ms a tick whatever the
 * number of players (call overhead of a few hundred small array operations); this one
 * a few microseconds a pose. Plain C, no SIMD: it runs on every machine the module
 * builds on, so it needs no instruction-set dispatch.
 *
 * Matrices are row-major 3x3 (m[3 * r + c]) acting on column vectors; quaternions are
 * xyzw. Joint numbers and parents are posecast.skeleton's (checked at import by
 * posecast.online.inference.native). */

#include <math.h>
#include <string.h>

#include "pc_geom.h"
#include "pc_upper.h"

enum { PELVIS, SPINE, CHEST, NECK, HEAD, L_UPPER, L_FORE, L_HAND, R_UPPER, R_FORE, R_HAND, NJ = 19 };
enum { S_HEAD, S_LHAND, S_RHAND };

#define EPS 1e-9       /* posecast.body.geom.EPS */
#define QEPS 1e-12     /* posecast.geometry.rotations._EPS (normalize) */

typedef double V3[3];
typedef double M3[9];

/* Each joint's subtree (the joints whose world pose a turn of it carries), -1 ended. */
static const int SUBTREE[NJ][10] = {
    [SPINE] = {CHEST, NECK, HEAD, L_UPPER, L_FORE, L_HAND, R_UPPER, R_FORE, R_HAND, -1},
    [CHEST] = {NECK, HEAD, L_UPPER, L_FORE, L_HAND, R_UPPER, R_FORE, R_HAND, -1},
    [NECK] = {HEAD, -1},
    [HEAD] = {-1},
};

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
static double norm3(const double *a) { return sqrt(dot3(a, a)); }
static void sub3(const double *a, const double *b, double *o) {
    o[0] = a[0] - b[0];
    o[1] = a[1] - b[1];
    o[2] = a[2] - b[2];
}
static void cross3(const double *a, const double *b, double *o) {
    double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2], z = a[0] * b[1] - a[1] * b[0];
    o[0] = x;
    o[1] = y;
    o[2] = z;
}
/* v / max(|v|, EPS); returns |v| (geom.unit3). */
static double unit3(const double *v, double *o) {
    double n = norm3(v), d = n > EPS ? n : EPS;
    o[0] = v[0] / d;
    o[1] = v[1] / d;
    o[2] = v[2] / d;
    return n;
}
static void mv(const double *m, const double *v, double *o) {
    double x = m[0] * v[0] + m[1] * v[1] + m[2] * v[2];
    double y = m[3] * v[0] + m[4] * v[1] + m[5] * v[2];
    double z = m[6] * v[0] + m[7] * v[1] + m[8] * v[2];
    o[0] = x;
    o[1] = y;
    o[2] = z;
}
static void mtm(const double *a, const double *b, double *o) { /* o = a^T b */
    M3 t;
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) t[3 * r + c] = a[r] * b[c] + a[3 + r] * b[3 + c] + a[6 + r] * b[6 + c];
    memcpy(o, t, sizeof(M3));
}
static void mmt(const double *a, const double *b, double *o) { /* o = a b^T */
    M3 t;
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++)
            t[3 * r + c] = a[3 * r] * b[3 * c] + a[3 * r + 1] * b[3 * c + 1] + a[3 * r + 2] * b[3 * c + 2];
    memcpy(o, t, sizeof(M3));
}

/* rotations.quat2mat (the quaternion normalised first). */
static void quat2mat(const double *qi, double *m) {
    double n = sqrt(qi[0] * qi[0] + qi[1] * qi[1] + qi[2] * qi[2] + qi[3] * qi[3]);
    double d = n > QEPS ? n : QEPS;
    double x = qi[0] / d, y = qi[1] / d, z = qi[2] / d, w = qi[3] / d;
    double xx = x * x, yy = y * y, zz = z * z, xy = x * y, xz = x * z, yz = y * z, wx = w * x, wy = w * y,
           wz = w * z;
    m[0] = 1 - 2 * (yy + zz);
    m[1] = 2 * (xy - wz);
    m[2] = 2 * (xz + wy);
    m[3] = 2 * (xy + wz);
    m[4] = 1 - 2 * (xx + zz);
    m[5] = 2 * (yz - wx);
    m[6] = 2 * (xz - wy);
    m[7] = 2 * (yz + wx);
    m[8] = 1 - 2 * (xx + yy);
}

/* rotations.axis_angle_mat: about the unit axis u by t radians (Rodrigues). */
static void axis_angle(const double *u, double t, double *m) {
    double c = cos(t), s = sin(t), x = u[0], y = u[1], z = u[2], k = 1.0 - c;
    m[0] = c + k * (x * x);
    m[1] = -s * z + k * (x * y);
    m[2] = s * y + k * (x * z);
    m[3] = s * z + k * (y * x);
    m[4] = c + k * (y * y);
    m[5] = -s * x + k * (y * z);
    m[6] = -s * y + k * (z * x);
    m[7] = s * x + k * (z * y);
    m[8] = c + k * (z * z);
}

/* upper_ik._part_of_swing: share of the swing from a to b, at most `most` radians. */
static void part_of_swing(const double *a, const double *b, double share, double most, double *R) {
    V3 ua, ub, v, axis;
    unit3(a, ua);
    unit3(b, ub);
    cross3(ua, ub, v);
    double s = norm3(v), c = dot3(ua, ub);
    double angle = s > EPS ? share * atan2(s, c) : 0.0;
    double d = s > EPS ? s : EPS;
    axis[0] = v[0] / d;
    axis[1] = v[1] / d;
    axis[2] = v[2] / d;
    axis_angle(axis, angle < most ? angle : most, R);
}

/* upper_ik._part_of_turn: share of the rotation R0, about its axis. */
static void part_of_turn(const double *R0, double share, double *R) {
    double q[4];
    pc_mat2quat(R0, q);
    if (q[3] < 0.0)
        for (int i = 0; i < 4; i++) q[i] = -q[i];
    double s = norm3(q), d = s > EPS ? s : EPS;
    V3 axis = {q[0] / d, q[1] / d, q[2] / d};
    axis_angle(axis, share * 2.0 * atan2(s, q[3]), R);
}

typedef struct {
    double pos[NJ][3];
    double mat[NJ][9];
} Pose;

/* upper_ik._turn: turn `joint` (and its subtree) by R about its own position. */
static void turn(Pose *p, int joint, const double *R) {
    const double *pivot = p->pos[joint];
    for (const int *s = SUBTREE[joint]; *s >= 0; s++) {
        V3 d;
        sub3(p->pos[*s], pivot, d);
        mv(R, d, d);
        p->pos[*s][0] = pivot[0] + d[0];
        p->pos[*s][1] = pivot[1] + d[1];
        p->pos[*s][2] = pivot[2] + d[2];
    }
    pc_mm(R, p->mat[joint], p->mat[joint]);
    for (const int *s = SUBTREE[joint]; *s >= 0; s++) pc_mm(R, p->mat[*s], p->mat[*s]);
}

/* upper_ik._point_bone: swing `joint` so its bone to `child` points at `target`. */
static void point_bone(Pose *p, int joint, int child, const double *target) {
    V3 a, b;
    M3 R;
    sub3(p->pos[child], p->pos[joint], a);
    sub3(target, p->pos[joint], b);
    pc_swing(a, b, R);
    turn(p, joint, R);
}

/* upper_ik._across: the part of v perpendicular to the unit u. */
static void across(const double *v, const double *u, double *o) {
    double k = dot3(v, u);
    o[0] = v[0] - k * u[0];
    o[1] = v[1] - k * u[1];
    o[2] = v[2] - k * u[2];
}

/* upper_ik.two_bone: elbow and hand of a limb from `sh` to a hand on `target`. */
static void two_bone(const double *sh, const double *elbow, const double *target, double l1, double l2,
                     const double *bend, double *new_elbow, double *hand) {
    V3 t, u, e, w;
    sub3(target, sh, t);
    double d = unit3(t, u);
    sub3(elbow, sh, e);
    across(e, u, t);
    double wn = unit3(t, w);
    const double fallbacks[3][3] = {{bend[0], bend[1], bend[2]}, {1.0, 0.0, 0.0}, {0.0, 1.0, 0.0}};
    for (int i = 0; i < 3 && wn < 1e-6; i++) {
        across(fallbacks[i], u, t);
        wn = unit3(t, w);
    }
    double lo = fabs(l1 - l2) + EPS, hi = l1 + l2;
    double dc = d > lo ? d : lo;
    dc = dc < hi ? dc : hi;
    double ca = (l1 * l1 + dc * dc - l2 * l2) / (2.0 * l1 * dc);
    ca = ca > -1.0 ? ca : -1.0;
    ca = ca < 1.0 ? ca : 1.0;
    double sa = sqrt(1.0 - ca * ca);
    for (int i = 0; i < 3; i++) {
        new_elbow[i] = sh[i] + l1 * (ca * u[i] + sa * w[i]);
        if (hand) hand[i] = sh[i] + dc * u[i];
    }
}

/* upper_ik._neck: the neck's world rotation under the chest. */
static void neck_rot(const double *chest, const double *neck_local, const double *head_local,
                     const double *head_mat, double share, double *out) {
    M3 held, rest, part;
    pc_mm(chest, neck_local, held);
    mtm(held, head_mat, rest);
    mmt(rest, head_local, rest);
    part_of_turn(rest, share, part);
    pc_mm(held, part, out);
}

/* One pose; `bone` the length of each joint's bone (from a->offsets). */
static void solve_one(const PcUpperArgs *a, const double *bone, int64_t e) {
    Pose p;
    const double *off = a->offsets;
    const float *pi = a->pos_in + e * NJ * 3, *qi = a->quat_in + e * NJ * 4;
    const double *tp = a->tp + e * a->slots * 3, *tq = a->tq + e * a->slots * 4;
    for (int j = 0; j < NJ; j++) {
        double q[4] = {qi[4 * j], qi[4 * j + 1], qi[4 * j + 2], qi[4 * j + 3]};
        for (int i = 0; i < 3; i++) p.pos[j][i] = pi[3 * j + i];
        quat2mat(q, p.mat[j]);
    }
    M3 tmat[3];
    for (int s = 0; s < 3; s++) quat2mat(tq + 4 * s, tmat[s]);
    const double *head_target = tp + 3 * S_HEAD;
    if (a->free && a->free[e]) { /* upper_ik.reach_shift */
        V3 v;
        sub3(head_target, p.pos[SPINE], v);
        double d = norm3(v), over = d - a->spine_reach;
        over = over > 0.0 ? over : 0.0;
        double k = over / (d > EPS ? d : EPS);
        V3 shift = {v[0] * k, v[1] * k, v[2] * k};
        for (int j = 0; j < NJ; j++)
            for (int i = 0; i < 3; i++) p.pos[j][i] += shift[i];
    }

    /* 1. The spine chain: the lean, the neck's share (twice), then the exact finish. */
    const double *head_mat = tmat[S_HEAD];
    M3 neck_local, head_local, R, nm;
    mtm(p.mat[CHEST], p.mat[NECK], neck_local);
    mtm(p.mat[NECK], p.mat[HEAD], head_local);
    const int lean[2] = {SPINE, CHEST};
    for (int i = 0; i < 2; i++) {
        V3 x, y;
        sub3(p.pos[HEAD], p.pos[lean[i]], x);
        sub3(head_target, p.pos[lean[i]], y);
        part_of_swing(x, y, a->lean_share, M_PI, R);
        turn(&p, lean[i], R);
    }
    const double len[3] = {bone[CHEST], bone[NECK], bone[HEAD]};
    for (int round = 0; round < 2; round++) {
        V3 forward = {p.mat[CHEST][2], p.mat[CHEST][5], p.mat[CHEST][8]}; /* the chest's +Z, live */
        V3 neck_at, ho, chest;
        neck_rot(p.mat[CHEST], neck_local, head_local, head_mat, a->neck_share, nm);
        mv(nm, off + 3 * HEAD, ho);
        sub3(head_target, ho, neck_at);
        two_bone(p.pos[SPINE], p.pos[CHEST], neck_at, len[0], len[1], forward, chest, NULL);
        point_bone(&p, SPINE, CHEST, chest);
        point_bone(&p, CHEST, NECK, neck_at);
        neck_rot(p.mat[CHEST], neck_local, head_local, head_mat, a->neck_share, nm);
        mmt(nm, p.mat[NECK], R);
        turn(&p, NECK, R);
    }
    { /* one FABRIK sweep (upper_ik.fabrik), then two two-bone solves */
        double sh[4][3];
        const int chain[4] = {SPINE, CHEST, NECK, HEAD};
        for (int i = 0; i < 4; i++) memcpy(sh[i], p.pos[chain[i]], sizeof(V3));
        V3 root, u, d;
        memcpy(root, sh[0], sizeof(V3));
        memcpy(sh[3], head_target, sizeof(V3));
        for (int i = 2; i >= 0; i--) {
            sub3(sh[i], sh[i + 1], d);
            unit3(d, u);
            for (int k = 0; k < 3; k++) sh[i][k] = sh[i + 1][k] + len[i] * u[k];
        }
        memcpy(sh[0], root, sizeof(V3));
        for (int i = 0; i < 3; i++) {
            sub3(sh[i + 1], sh[i], d);
            unit3(d, u);
            for (int k = 0; k < 3; k++) sh[i + 1][k] = sh[i][k] + len[i] * u[k];
        }
        sub3(head_target, sh[1], d);
        double span = norm3(d), lo = fabs(len[1] - len[2]), hi = len[1] + len[2];
        span = span > lo ? span : lo;
        span = span < hi ? span : hi;
        V3 forward = {p.mat[CHEST][2], p.mat[CHEST][5], p.mat[CHEST][8]};
        V3 chest, neck, head;
        two_bone(p.pos[SPINE], sh[1], head_target, len[0], span, forward, chest, NULL);
        two_bone(chest, sh[2], head_target, len[1], len[2], forward, neck, head);
        point_bone(&p, SPINE, CHEST, chest);
        point_bone(&p, CHEST, NECK, neck);
        point_bone(&p, NECK, HEAD, head);
        memcpy(p.mat[HEAD], head_mat, sizeof(M3));
    }

    /* 2. Both arms (each with the left arm's bone lengths, as the reference does). */
    const int upper[2] = {L_UPPER, R_UPPER}, fore[2] = {L_FORE, R_FORE}, hand[2] = {L_HAND, R_HAND};
    const double down[3] = {0.0, -1.0, 0.0}; /* where a straight network arm bends */
    for (int k = 0; k < 2; k++) {
        const double *target = tp + 3 * (S_LHAND + k);
        const double *tm = tmat[S_LHAND + k];
        V3 shoulder, hint, elbow, wrist, x, y;
        memcpy(shoulder, p.pos[upper[k]], sizeof(V3));
        memcpy(hint, p.pos[fore[k]], sizeof(V3));
        if (a->wrist_share > 0.0) { /* upper_ik.straight_forearms */
            V3 dir, fwd;
            for (int i = 0; i < 3; i++) dir[i] = off[3 * hand[k] + i] / bone[hand[k]];
            mv(tm, dir, fwd);
            for (int i = 0; i < 3; i++) {
                double behind = target[i] - bone[L_HAND] * fwd[i];
                hint[i] = (1.0 - a->wrist_share) * hint[i] + a->wrist_share * behind;
            }
        }
        two_bone(shoulder, hint, target, bone[L_FORE], bone[L_HAND], down, elbow, wrist);
        sub3(p.pos[fore[k]], shoulder, x);
        sub3(elbow, shoulder, y);
        pc_swing(x, y, R);
        const int carried[2] = {fore[k], hand[k]};
        for (int i = 0; i < 2; i++) {
            sub3(p.pos[carried[i]], shoulder, x);
            mv(R, x, x);
            for (int c = 0; c < 3; c++) p.pos[carried[i]][c] = shoulder[c] + x[c];
        }
        pc_mm(R, p.mat[upper[k]], p.mat[upper[k]]);
        pc_mm(R, p.mat[fore[k]], p.mat[fore[k]]);
        sub3(p.pos[hand[k]], p.pos[fore[k]], x);
        sub3(wrist, p.pos[fore[k]], y);
        pc_swing(x, y, R);
        sub3(p.pos[hand[k]], p.pos[fore[k]], x);
        mv(R, x, x);
        for (int c = 0; c < 3; c++) p.pos[hand[k]][c] = p.pos[fore[k]][c] + x[c];
        pc_mm(R, p.mat[fore[k]], p.mat[fore[k]]);
        memcpy(p.mat[hand[k]], tm, sizeof(M3));
    }

    /* 3. What was not reached; the outputs. */
    const int eff[3] = {HEAD, L_HAND, R_HAND};
    uint8_t limited = 0;
    for (int s = 0; s < 3; s++) {
        V3 d;
        sub3(p.pos[eff[s]], tp + 3 * s, d);
        if (norm3(d) > a->reach_tol) limited = 1;
    }
    a->limited[e] = limited;
    float *po = a->pos_out + e * NJ * 3, *qo = a->quat_out + e * NJ * 4;
    for (int j = 0; j < NJ; j++) {
        for (int i = 0; i < 3; i++) po[3 * j + i] = (float)p.pos[j][i];
        if (j >= SPINE && j <= R_HAND) {
            double q[4];
            pc_mat2quat(p.mat[j], q);
            for (int i = 0; i < 4; i++) qo[4 * j + i] = (float)q[i];
        } else {
            for (int i = 0; i < 4; i++) qo[4 * j + i] = qi[4 * j + i];
        }
    }
}

void pc_upper_rows(const PcUpperArgs *a, int64_t r0, int64_t r1) {
    double bone[NJ];
    for (int j = 0; j < NJ; j++) bone[j] = norm3(a->offsets + 3 * j);
    for (int64_t e = r0; e < r1; e++) solve_one(a, bone, e);
}

/* --- the hinges (posecast.body.hinge._hinge on quaternions) ------------------ */

/* upper_ik._wrap: into [-pi, pi), as Python's float modulo. */
static double wrap_angle(double x) {
    double r = fmod(x + M_PI, 2.0 * M_PI);
    if (r < 0.0) r += 2.0 * M_PI;
    return r - M_PI;
}

static void hinge_one(const PcHingeArgs *h, int64_t e) {
    const float *pf = h->pos + e * NJ * 3;
    float *qf = h->quat + e * NJ * 4;
    for (int64_t l = 0; l < h->limbs; l++) {
        const double *spec = h->spec + 9 * l;
        int upper = (int)spec[0], lower = (int)spec[1], end = (int)spec[2];
        const double *axis = spec + 3, *behind_local = spec + 6;
        V3 pu, pl, pe, d, a, f, bend, behind, t;
        for (int i = 0; i < 3; i++) {
            pu[i] = pf[3 * upper + i];
            pl[i] = pf[3 * lower + i];
            pe[i] = pf[3 * end + i];
        }
        sub3(pl, pu, d);
        unit3(d, a);
        sub3(pe, pl, d);
        unit3(d, f);
        double c = dot3(a, f);
        c = c > -1.0 ? c : -1.0;
        c = c < 1.0 ? c : 1.0;
        for (int i = 0; i < 3; i++) t[i] = f[i] - c * a[i];
        unit3(t, bend);
        double w = (sqrt(1.0 - c * c) - h->straight) / h->span;
        w = w > 0.0 ? w : 0.0;
        w = w < 1.0 ? w : 1.0;
        M3 Rt, Rs, R, hinged;
        double q[4];
        for (int i = 0; i < 4; i++) q[i] = qf[4 * upper + i];
        quat2mat(q, Rt);
        for (int i = 0; i < 4; i++) q[i] = qf[4 * lower + i];
        quat2mat(q, Rs);
        mv(Rt, behind_local, t);
        double k = dot3(t, a);
        for (int i = 0; i < 3; i++) t[i] = t[i] - k * a[i];
        unit3(t, behind);
        cross3(behind, bend, t);
        double alpha = atan2(dot3(t, a), dot3(behind, bend));
        double fade = (h->flip - fabs(alpha)) / h->flip_span;
        fade = fade > 0.0 ? fade : 0.0;
        fade = fade < 1.0 ? fade : 1.0;
        w = w * fade;
        axis_angle(a, alpha * w, R);
        pc_mm(R, Rt, Rt);
        axis_angle(axis, acos(c), R);
        pc_mm(Rt, R, hinged);
        mmt(hinged, Rs, R); /* hinge._twist_angle of hinged Rs^T about f */
        V3 v = {R[7] - R[5], R[2] - R[6], R[3] - R[1]};
        double beta = wrap_angle(2.0 * atan2(dot3(v, f), 1.0 + R[0] + R[4] + R[8]));
        axis_angle(f, beta * w, R);
        pc_mm(R, Rs, Rs);
        pc_mat2quat(Rt, q);
        for (int i = 0; i < 4; i++) qf[4 * upper + i] = (float)q[i];
        pc_mat2quat(Rs, q);
        for (int i = 0; i < 4; i++) qf[4 * lower + i] = (float)q[i];
    }
}

void pc_hinge_rows(const PcHingeArgs *h, int64_t r0, int64_t r1) {
    for (int64_t e = r0; e < r1; e++) hinge_one(h, e);
}
