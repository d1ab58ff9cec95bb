/* A tool pressed into a body through the C ABI (docs/contact.md): the sphere's centre moves
 * along -n from a surface point p (start: touching) to `depth`, then grasps the node under it
 * and pulls it back out to p; the force on the tool is printed every step.
 *
 *   touch MODEL px py pz nx ny nz depth steps
 *
 * A haptic device loop would call crokf_step_with_tools once per tick with the device's
 * position and render -force (the body's force on the tool) or use the stiffness between
 * ticks. */
#include <stdio.h>
#include <stdlib.h>

#include "crokf.h"

int main(int argc, char **argv) {
    if (argc != 10) {
        fprintf(stderr, "usage: %s MODEL px py pz nx ny nz depth steps\n", argv[0]);
        return 2;
    }
    CrokfModel *model = crokf_model_load(argv[1]);
    if (!model) {
        fprintf(stderr, "error: %s\n", crokf_last_error());
        return 1;
    }
    if (!crokf_model_has_contact(model)) {
        fprintf(stderr, "error: %s has no contact region\n", argv[1]);
        return 1;
    }
    double p[3], n[3];
    for (int i = 0; i < 3; i++) {
        p[i] = atof(argv[2 + i]);
        n[i] = atof(argv[5 + i]);
    }
    double depth = atof(argv[8]);
    int steps = atoi(argv[9]);
    size_t m = crokf_model_num_inputs(model);
    CrokfEstimator *est = crokf_estimator_new(model);
    crokf_model_free(model);
    if (!est) {
        fprintf(stderr, "error: %s\n", crokf_last_error());
        return 1;
    }
    double *u = calloc(m + 1, sizeof(double));
    for (int k = 1; k <= steps; k++) {
        double d = depth * k / steps;
        double tool[3];
        for (int i = 0; i < 3; i++) tool[i] = p[i] - n[i] * d;
        CrokfToolContact c;
        if (crokf_step_with_tools(est, tool, 1, u, m, NULL, NULL, 0) < 0 ||
            crokf_tool_contact(est, 0, &c) != 0) {
            fprintf(stderr, "error: %s\n", crokf_last_error());
            return 1;
        }
        printf("%d %.17g %.17g %.17g %u %d\n", k, c.force[0], c.force[1], c.force[2],
               c.active, c.status);
    }
    /* Grasp the node under the tool and pull it back out to where the press began. */
    size_t node = 0;
    if (crokf_grasp(est, 0, &node) != 0) {
        fprintf(stderr, "error: %s\n", crokf_last_error());
        return 1;
    }
    printf("grasped %zu\n", node);
    for (int k = 1; k <= steps; k++) {
        double d = depth * (steps - k) / steps;
        double tool[3];
        for (int i = 0; i < 3; i++) tool[i] = p[i] - n[i] * d;
        CrokfToolContact c;
        if (crokf_step_with_tools(est, tool, 1, u, m, NULL, NULL, 0) < 0 ||
            crokf_tool_contact(est, 0, &c) != 0) {
            fprintf(stderr, "error: %s\n", crokf_last_error());
            return 1;
        }
        printf("%d %.17g %.17g %.17g %u %d\n", steps + k, c.force[0], c.force[1], c.force[2],
               c.active, c.status);
    }
    if (crokf_release(est, 0) != 0) return 4;
    /* Three tools are refused, the estimator unchanged. */
    double three[9] = {0};
    if (crokf_step_with_tools(est, three, 3, u, m, NULL, NULL, 0) != -1) return 3;
    printf("refused: %s\n", crokf_last_error());
    crokf_estimator_free(est);
    free(u);
    return 0;
}
