/* Short host processes of the unit, by test/outputs/test_fmu_native.py: argv BINARY GUID RESOURCE_URI COUNT.
   COUNT children each load the unit (dlopen), run it through a whole lifecycle and exit; prints how many
   exited 0, how many otherwise and how many were killed by a signal (an abort at exit among them). */
#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status, fmi2String category,
                   fmi2String message, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)message;
}

static void *allocate(size_t n, size_t size) { return calloc(n, size); }

#define SYMBOL(type, name) type name = (type)dlsym(unit, #name); if (name == NULL) _exit(3)

static int host(const char *binary, const char *guid, const char *resources) {
    const fmi2CallbackFunctions callbacks = {logger, allocate, free, NULL, NULL};
    const fmi2ValueReference in[3] = {0, 1, 2}, out[3] = {3, 4, 5};
    double x[3] = {12.5, 80.0, 40.0}, y[3];
    fmi2Component c;
    int i;
    void *unit = dlopen(binary, RTLD_NOW | RTLD_LOCAL);
    if (unit == NULL) return 4;
    {
        SYMBOL(fmi2InstantiateTYPE *, fmi2Instantiate);
        SYMBOL(fmi2SetupExperimentTYPE *, fmi2SetupExperiment);
        SYMBOL(fmi2EnterInitializationModeTYPE *, fmi2EnterInitializationMode);
        SYMBOL(fmi2ExitInitializationModeTYPE *, fmi2ExitInitializationMode);
        SYMBOL(fmi2SetRealTYPE *, fmi2SetReal);
        SYMBOL(fmi2GetRealTYPE *, fmi2GetReal);
        SYMBOL(fmi2DoStepTYPE *, fmi2DoStep);
        SYMBOL(fmi2TerminateTYPE *, fmi2Terminate);
        SYMBOL(fmi2FreeInstanceTYPE *, fmi2FreeInstance);
        c = fmi2Instantiate("host", fmi2CoSimulation, guid, resources, &callbacks, fmi2False, fmi2False);
        if (c == NULL) return 5;
        if (fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK
            || fmi2EnterInitializationMode(c) != fmi2OK || fmi2ExitInitializationMode(c) != fmi2OK) return 6;
        for (i = 0; i < 3; i++) {
            x[1] += 1.0;
            if (fmi2SetReal(c, in, 3, x) != fmi2OK || fmi2DoStep(c, 0.01 * i, 0.01, fmi2True) != fmi2OK
                || fmi2GetReal(c, out, 3, y) != fmi2OK || !(y[0] > 0.0)) return 7;
        }
        if (fmi2Terminate(c) != fmi2OK) return 8;
        fmi2FreeInstance(c);
    }
    return dlclose(unit) == 0 ? 0 : 9;
}

int main(int argc, char **argv) {
    int count, i, ok = 0, failed = 0, signalled = 0;
    if (argc != 5) return 2;
    count = atoi(argv[4]);
    for (i = 0; i < count; i++) {
        int status;
        pid_t pid = fork();
        if (pid < 0) return 3;
        if (pid == 0) exit(host(argv[1], argv[2], argv[3])); /* exit: the C library's whole teardown */
        if (waitpid(pid, &status, 0) != pid) return 3;
        if (WIFSIGNALED(status)) signalled++;
        else if (WEXITSTATUS(status) == 0) ok++;
        else failed++;
    }
    printf("%d %d %d\n", ok, failed, signalled);
    return 0;
}
