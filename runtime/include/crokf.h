/*
 * crokf.h - C interface of the crokf runtime (libcrokf_runtime).
 *
 * Conventions: functions returning int give 0 (or a count >= 0) on success and -1 on
 * failure; functions returning a pointer give NULL on failure. The reason of the last failure
 * on the calling thread is crokf_last_error(). No Rust panic crosses this boundary.
 *
 * Units: metres, newtons, seconds, radians. Vectors of 3 per sensor/node are (x, y, z) in the
 * world frame. Step k = 1, 2, ... is the k-th prediction; its estimate is at t = k * dt.
 */
#ifndef CROKF_H
#define CROKF_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct CrokfModel CrokfModel;         /* a loaded, validated model file */
typedef struct CrokfEstimator CrokfEstimator; /* filter state over a model (shares its matrices) */

/* Message of the last failed call on this thread ("" if none); valid until the next failure. */
const char *crokf_last_error(void);

/* Models. */
CrokfModel *crokf_model_load(const char *path);
CrokfModel *crokf_model_from_bytes(const uint8_t *bytes, size_t len);
void crokf_model_free(CrokfModel *model); /* NULL is a no-op */

size_t crokf_model_num_inputs(const CrokfModel *model);       /* m */
size_t crokf_model_num_measurements(const CrokfModel *model); /* q */
size_t crokf_model_num_sensors(const CrokfModel *model);
size_t crokf_model_state_dim(const CrokfModel *model);        /* r, or 3 r_tier + 3 per force group (q, q', q'', f), 6 with force rates (f') */
size_t crokf_model_is_corotational(const CrokfModel *model);  /* 1: co-rotational tier */
size_t crokf_model_num_node_sets(const CrokfModel *model);
size_t crokf_model_node_set_len(const CrokfModel *model, size_t set); /* nodes */
double crokf_model_dt(const CrokfModel *model);               /* s */
/* Labels live as long as the model; NULL if out of range. */
const char *crokf_model_input_label(const CrokfModel *model, size_t i);
const char *crokf_model_measurement_label(const CrokfModel *model, size_t i); /* "sensor.x" */
const char *crokf_model_sensor_name(const CrokfModel *model, size_t i);
const char *crokf_model_node_set_name(const CrokfModel *model, size_t i);

/* Estimators (the model may be freed after creating one; estimators share its matrices). */
CrokfEstimator *crokf_estimator_new(const CrokfModel *model);
void crokf_estimator_free(CrokfEstimator *est); /* NULL is a no-op */

/* x- = F x + G R^T(omega) u: n_inputs = m world-frame inputs (N; gravity: a scale factor).
 * Non-finite inputs and inputs beyond the model's plausibility bound fail (state untouched). */
int crokf_predict(CrokfEstimator *est, const double *inputs, size_t n_inputs);
/* Update of the current phase. y: q world-frame values (m); present[i] == 0 marks y[i]
 * missing (present NULL: all present; y NULL: no measurement this step). Returns the number of
 * values used. A non-finite present value fails and leaves the state untouched. */
int crokf_update(CrokfEstimator *est, const double *y, const uint8_t *present, size_t n);
/* crokf_predict then crokf_update, all or nothing: on failure (-1) the estimator is exactly as
 * before the call (step index included). */
int crokf_step(CrokfEstimator *est, const double *inputs, size_t n_inputs,
               const double *y, const uint8_t *present, size_t n);
/* Innovation gate: a present measurement whose innovation exceeds `sigmas` standard deviations
 * of its innovation covariance is skipped for that step and counted (default 5; a value that is
 * not finite and > 0 turns the gate off). */
int crokf_set_innovation_gate(CrokfEstimator *est, double sigmas);
uint64_t crokf_gated_count(const CrokfEstimator *est); /* skipped since creation/reset */
int crokf_reset(CrokfEstimator *est);
uint64_t crokf_step_index(const CrokfEstimator *est);
/* Co-rotational tier: last step's Newton iterations, load ratio |f_g|/max_force_g and state
 * ratio |q|/max training |q| (NULL pointers skipped). 1: outside the training envelope,
 * 0: inside (always 0 for the warped tier), -1: NULL handle. A step the tier cannot take
 * (Newton not converged, inverted element) fails with -1 and leaves the estimator unchanged. */
int crokf_tier_status(const CrokfEstimator *est, size_t *iterations, double *load_ratio,
                      double *state_ratio);
/* Co-rotational tier with force-σ levels: the level in use (0: the designed σ), its factor on
 * the designed σ and the innovation statistic (NULL pointers skipped). 1: the model has levels,
 * 0: it has one (nothing written), -1: NULL handle. */
int crokf_force_level(const CrokfEstimator *est, size_t *level, double *factor,
                      double *statistic);
/* on != 0: the level follows the innovations (default); 0: it stays at the designed σ. On
 * before the first step after creation or reset, the run's first update is made at the lowest
 * level (markers every step, docs/design.md §11.10). */
int crokf_set_force_adaptation(CrokfEstimator *est, int on);
/* Co-rotational tier: from an update with an active channel missing or gated, or from a
 * lowering of the force-σ level after an update, until its covariance settles, the filter
 * carries its own covariance P (docs/design.md §11.10–11.11).
 * on != 0: so (default); 0: the stored gains and σ. */
int crokf_set_covariance_recursion(CrokfEstimator *est, int on);
/* P (n*n doubles row-major, n = crokf_model_state_dim) while the filter carries it: 1 written,
 * 0 the stored covariances in use (nothing written), -1 wrong length or NULL. */
int crokf_tier_covariance(const CrokfEstimator *est, double *out, size_t len);

/* Contact (docs/contact.md): a rigid sphere tool on the model's contact region, warped tier.
 * The tool centres are 3 doubles per tool (m, the model's frame), at most 2 tools. */
typedef struct CrokfToolContact {
    double force[3];     /* N: the body on the tool */
    double torque[3];    /* N m: about the tool's centre */
    double stiffness[9]; /* N/m, row-major: the force changes by -K dc for a small move dc */
    double force_std[3]; /* N: with crokf_set_contact_force_std on, else 0 */
    double depth;        /* m: deepest penetration of the free prediction */
    uint32_t active;     /* region nodes pressing */
    int32_t status;      /* 0 free, 1 touching, 2 clamped at the force bound, 3 overflow,
                            4 not converged, 5 grasping */
} CrokfToolContact;
size_t crokf_model_has_contact(const CrokfModel *model); /* 1: a contact region */
/* Why the model's co-rotational tier failed the compiler's check (written all the same, scene
   `accept_failed_check = true`), or NULL when it passed or there is no tier. Lives as long as
   the model handle. */
const char *crokf_model_tier_failed_check(const CrokfModel *model);
/* crokf_step with tools, all or nothing (-1: the estimator exactly as before the call). */
int crokf_step_with_tools(CrokfEstimator *est, const double *tools, size_t n_tools,
                          const double *inputs, size_t n_inputs,
                          const double *y, const uint8_t *present, size_t n);
/* The last contact step's result for tool `tool`: 0, or -1 (no such tool in that step). */
int crokf_tool_contact(const CrokfEstimator *est, size_t tool, CrokfToolContact *out);
int crokf_set_contact_force_std(CrokfEstimator *est, int on); /* on != 0: compute the force's sigma */
/* Tool `tool` of the last tool step grasps the region node nearest its centre (within 1.25
 * radii) and holds it at its centre plus the node's present offset from the next step on,
 * pushing nowhere else: 0 and the node's region index in *node (node may be NULL), or -1 and
 * nothing changed. crokf_release lets go (0, or -1 on a NULL handle). */
int crokf_grasp(CrokfEstimator *est, size_t tool, size_t *node);
int crokf_release(CrokfEstimator *est, size_t tool);

/* Read-outs into caller buffers; len must be exact. A read-out never succeeds with a
 * non-finite value. */
int crokf_sensor_displacements(const CrokfEstimator *est, double *out, size_t len); /* 3*sensors */
int crokf_sensor_std(const CrokfEstimator *est, double *out, size_t len);           /* 3*sensors */
int crokf_measurement_estimates(const CrokfEstimator *est, double *out, size_t len); /* q */
int crokf_node_displacements(const CrokfEstimator *est, size_t set, double *out, size_t len);
int crokf_node_positions(const CrokfEstimator *est, size_t set, double *out, size_t len);
int crokf_node_std(const CrokfEstimator *est, size_t set, double *out, size_t len);
int crokf_state(const CrokfEstimator *est, double *out, size_t len); /* crokf_model_state_dim */

#ifdef __cplusplus
}
#endif

#endif /* CROKF_H */
