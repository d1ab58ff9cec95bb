/* Loads a model, runs a few steps with a constant unit input on every channel and no
 * measurements except step 2 (zeros), and prints the sensor read-outs.
 * Build: cc example.c -I runtime/include -L target/debug -lcrokf_runtime -o example
 * Run:   ./example model.crokf [steps]                                                  */
#include <stdio.h>
#include <stdlib.h>
#include "crokf.h"

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s MODEL [STEPS]\n", argv[0]);
        return 2;
    }
    int steps = argc > 2 ? atoi(argv[2]) : 5;
    CrokfModel *model = crokf_model_load(argv[1]);
    if (!model) {
        fprintf(stderr, "error: %s\n", crokf_last_error());
        return 1;
    }
    size_t m = crokf_model_num_inputs(model), q = crokf_model_num_measurements(model);
    size_t ns = crokf_model_num_sensors(model);
    printf("model: r=%zu inputs=%zu measurements=%zu sensors=%zu dt=%g\n",
           crokf_model_state_dim(model), m, q, ns, crokf_model_dt(model));
    CrokfEstimator *est = crokf_estimator_new(model);
    crokf_model_free(model);
    if (!est) {
        fprintf(stderr, "error: %s\n", crokf_last_error());
        return 1;
    }
    double *u = calloc(m ? m : 1, sizeof(double));
    double *y = calloc(q ? q : 1, sizeof(double));
    double *d = calloc(3 * ns + 1, sizeof(double));
    double *s = calloc(3 * ns + 1, sizeof(double));
    for (size_t i = 0; i < m; i++) u[i] = 1.0;
    for (int k = 1; k <= steps; k++) {
        int used = crokf_step(est, u, m, k == 2 ? y : NULL, NULL, q);
        if (used < 0 || crokf_sensor_displacements(est, d, 3 * ns) != 0 ||
            crokf_sensor_std(est, s, 3 * ns) != 0) {
            fprintf(stderr, "error: %s\n", crokf_last_error());
            return 1;
        }
        printf("step %d used %d:", k, used);
        for (size_t i = 0; i < 3 * ns; i++) printf(" %.17g", d[i]);
        printf(" | std:");
        for (size_t i = 0; i < 3 * ns; i++) printf(" %.17g", s[i]);
        printf("\n");
    }
    /* A failing call must report an error, not crash. */
    if (crokf_sensor_displacements(est, d, 3 * ns + 1) != -1) return 3;
    printf("expected error: %s\n", crokf_last_error());
    /* A refused step (an implausible input) leaves the estimator exactly as it was. */
    if (m > 0) {
        uint64_t k0 = crokf_step_index(est);
        double *before = calloc(3 * ns + 1, sizeof(double));
        if (crokf_sensor_displacements(est, before, 3 * ns) != 0) return 4;
        u[0] = 1e300;
        if (crokf_step(est, u, m, NULL, NULL, q) != -1) return 5;
        printf("refused step: %s\n", crokf_last_error());
        if (crokf_step_index(est) != k0) return 6;
        if (crokf_sensor_displacements(est, d, 3 * ns) != 0) return 7;
        for (size_t i = 0; i < 3 * ns; i++)
            if (d[i] != before[i]) return 8;
        printf("after the refused step: step %llu, read-outs unchanged, gated %llu\n",
               (unsigned long long)crokf_step_index(est),
               (unsigned long long)crokf_gated_count(est));
        free(before);
    }
    crokf_estimator_free(est);
    free(u); free(y); free(d); free(s);
    return 0;
}
