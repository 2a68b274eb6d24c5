/* The unit's FMI 2.0 lifecycle, built with its own sources under AddressSanitizer and UBSan by
   test/outputs/test_fmu_native.py: argv GUID RESOURCE_URI SEED OTHERS.  An instance that was refused calls
   is freed after OTHERS instances came and went, each through a random part of its lifecycle (steps with
   hostile inputs, reset, terminate) and freed in a random order; bad instantiations give NULL.  Prints
   "ok" and exits 0, or names the line that failed and exits 1 (a memory error aborts under the sanitizer). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"

static int logged = 0;

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)message;
    logged++;
}

static void *allocate(size_t n, size_t size) { return calloc(n, size); }
static const fmi2CallbackFunctions callbacks = {logger, allocate, free, NULL, NULL};

#define CHECK(cond) do { if (!(cond)) { fprintf(stderr, "line %d: %s\n", __LINE__, #cond); exit(1); } } while (0)

static double hostile(void) {
    static const double values[] = {NAN, INFINITY, -INFINITY, 1e308, -1e308, 5e-324, -0.0, 1e6, 12.5, 80.0, 40.0};
    return values[rand() % (int)(sizeof values / sizeof values[0])];
}

static void steps(fmi2Component c, int n) {
    const fmi2ValueReference in[3] = {0, 1, 2}, out[3] = {3, 4, 5}, inside_vr = 0, flags_vr[3] = {0, 1, 2};
    int i;
    for (i = 0; i < n; i++) {
        double x[3], y[3];
        fmi2Boolean inside, flags[3];
        x[0] = hostile(); x[1] = hostile(); x[2] = hostile();
        CHECK(fmi2SetReal(c, in, 3, x) == fmi2OK);
        CHECK(fmi2DoStep(c, 0.01 * i, 0.01, fmi2True) == fmi2OK);
        CHECK(fmi2GetReal(c, out, 3, y) == fmi2OK);
        CHECK(fmi2GetBoolean(c, &inside_vr, 1, &inside) == fmi2OK);
        CHECK(fmi2GetBoolean(c, flags_vr, 3, flags) == fmi2OK && flags[0] == inside);
        if (!inside) CHECK(!flags[1] && !flags[2]);
        if (!isfinite(x[0]) || !isfinite(x[1]) || !isfinite(x[2])) CHECK(!inside);
        if (!inside) CHECK(isnan(y[0]) && isnan(y[1]) && isnan(y[2]));
        else CHECK(isfinite(y[0]) && y[0] >= 0.0 && isfinite(y[1]));
    }
}

/* a random part of the lifecycle, in an order FMI 2.0 allows */
static void lifecycle(fmi2Component c) {
    const int stage = rand() % 7;
    if (stage >= 1) CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) == fmi2OK);
    if (stage >= 2) CHECK(fmi2EnterInitializationMode(c) == fmi2OK);
    if (stage >= 3) CHECK(fmi2ExitInitializationMode(c) == fmi2OK);
    if (stage >= 4) steps(c, 1 + rand() % 5);
    if (stage >= 5) CHECK(fmi2Terminate(c) == fmi2OK);
    if (stage >= 6) {
        CHECK(fmi2Reset(c) == fmi2OK);
        CHECK(fmi2EnterInitializationMode(c) == fmi2OK);
        CHECK(fmi2ExitInitializationMode(c) == fmi2OK);
        steps(c, 2);
    }
}

int main(int argc, char **argv) {
    const char *guid, *resources;
    fmi2Component pool[600], refused;
    const fmi2ValueReference output = 3, parameter = 6, text = 0, missing = 99;
    const double value = 1.0;
    double read;
    const char *set_text = "x";
    fmi2String got;
    int others, n = 0, i;
    if (argc != 5) return 2;
    guid = argv[1];
    resources = argv[2];
    srand((unsigned)atoi(argv[3]));
    others = atoi(argv[4]);
    CHECK(others >= 0 && others <= 500);

    refused = fmi2Instantiate("refused", fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2False);
    CHECK(refused != NULL);
    CHECK(fmi2DoStep(refused, 0.0, 0.1, fmi2True) == fmi2Error); /* before initialization */
    CHECK(fmi2SetReal(refused, &output, 1, &value) == fmi2Error); /* an output */
    CHECK(fmi2SetReal(refused, &parameter, 1, &value) == fmi2Error); /* a calculated parameter */
    CHECK(fmi2SetString(refused, &text, 1, &set_text) == fmi2Error);
    CHECK(fmi2GetReal(refused, &missing, 1, &read) == fmi2Error);
    CHECK(fmi2GetString(refused, &text, 1, &got) == fmi2OK && got != NULL && got[0] != '\0');
    CHECK(fmi2ExitInitializationMode(refused) == fmi2Error);
    CHECK(fmi2GetFMUstate(refused, NULL) == fmi2Error);

    for (i = 0; i < others; i++) {
        fmi2Component c = fmi2Instantiate("other", fmi2CoSimulation, guid, resources, &callbacks, fmi2False,
                                          (fmi2Boolean)(i % 2));
        CHECK(c != NULL);
        lifecycle(c);
        pool[n++] = c;
        if (n > 0 && rand() % 3 == 0) { /* one of those alive goes, any of them */
            int k = rand() % n;
            fmi2FreeInstance(pool[k]);
            pool[k] = pool[--n];
        }
    }
    fmi2FreeInstance(refused);
    while (n > 0) {
        int k = rand() % n;
        fmi2FreeInstance(pool[k]);
        pool[k] = pool[--n];
    }
    fmi2FreeInstance(NULL);

    CHECK(fmi2Instantiate("me", fmi2ModelExchange, guid, resources, &callbacks, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate("guid", fmi2CoSimulation, "{another}", resources, &callbacks, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate("nowhere", fmi2CoSimulation, guid, "file:///nonexistent/resources", &callbacks, fmi2False,
                          fmi2False) == NULL);
    CHECK(fmi2Instantiate("no uri", fmi2CoSimulation, guid, NULL, &callbacks, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate(NULL, fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2False) == NULL);
    CHECK(fmi2Instantiate("no callbacks", fmi2CoSimulation, guid, resources, NULL, fmi2False, fmi2False) == NULL);
    printf("ok %d\n", logged);
    return 0;
}
