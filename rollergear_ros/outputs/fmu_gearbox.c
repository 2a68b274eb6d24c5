/*
 * rollergear_gearbox: the calibrated roller gearing gearbox's losses as an FMI 2.0 co-simulation unit.
 *
 * Written by rollergear_ros (`rollergear export --fmu`); it builds with any C99 compiler against the FMI 2.0
 * headers beside it and rollergear_table.h, the table's grid and constants the export generated:
 *
 *     cc -shared -fPIC -O2 -std=c99 -I. -o rollergear_gearbox.so rollergear_gearbox.c -lm
 *
 * The loss table (N*m, little-endian doubles, C order [speed][torque][oil temperature]) is the unit's
 * resource rollergear_loss.f64, read once at instantiation; after it nothing is allocated.  Each step
 * interpolates it trilinearly at the inputs:
 *
 *   inputs   drive_torque_nm [N*m], drive_speed_rad_s [rad/s] (signed: negative torque with positive speed
 *            regenerates), oil_temperature_c [degC];
 *   outputs  loss_torque_nm [N*m] (input-referred magnitude, as a VECTO map), loss_power_w [W] =
 *            loss_torque_nm*|w|, efficiency [1] (eq. 30 in four quadrants: motoring (|T| - T_loss)/|T|,
 *            regenerating |T|/(|T| + T_loss); NaN where undefined: |T| or |w| below the estimator's
 *            thresholds), inside_table (false: an input is not finite or lies beyond the table, and every
 *            other output is NaN -- the table says nothing there), inside_calibration (the point lies within
 *            what the calibration analysed: |w| and |T| at most the largest it saw, the oil within its span
 *            where the model follows the oil; false where the parameter file states no calibrated range),
 *            inside_rating (|w| and |T| at most the gearbox's rating).
 *
 * Value references: Real 0 drive_torque_nm, 1 drive_speed_rad_s, 2 oil_temperature_c, 3 loss_torque_nm,
 * 4 loss_power_w, 5 efficiency, 6 interpolation_error_nm, 7 interpolation_error_relative; Boolean 0
 * inside_table, 1 inside_calibration, 2 inside_rating; String 0 ... RG_N_STRINGS - 1 the provenance.
 *
 * No input makes a step fail: NaN or infinite inputs give NaN outputs.  Setting an output, a calculated
 * parameter or a variable that does not exist is refused (fmi2Error, logged); so is a call out of the
 * order FMI 2.0 allows.  An instance is freed whole by fmi2FreeInstance in any state.
 */

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "rollergear_table.h"

#define RG_MAGIC 0x52474258u /* "RGBX": a pointer that is not one of our instances is refused */
#define RG_NODES ((size_t)RG_NS * (size_t)RG_NT * (size_t)RG_NK)

enum { VR_TORQUE, VR_SPEED, VR_OIL, VR_LOSS, VR_POWER, VR_EFFICIENCY, VR_ERROR_NM, VR_ERROR_RELATIVE, VR_REALS };
enum { VB_INSIDE_TABLE, VB_INSIDE_CALIBRATION, VB_INSIDE_RATING, VB_BOOLEANS };

typedef enum { INSTANTIATED = 1, INITIALIZING = 2, STEPPING = 4, TERMINATED = 8, FAILED = 16 } Mode;

typedef struct {
    unsigned magic;
    Mode mode;
    int logging;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment environment;
    char name[256];
    double *loss; /* RG_NODES values, read at instantiation */
    double real[VR_REALS];
    fmi2Boolean boolean[VB_BOOLEANS];
    double time;
} Instance;

static void say(const Instance *c, fmi2Status status, const char *category, const char *message) {
    if (c->logger != NULL && (c->logging || status != fmi2OK)) {
        c->logger(c->environment, c->name, status, category, "%s", message);
    }
}

static fmi2Status refuse(const Instance *c, const char *message) {
    say(c, fmi2Error, "logStatusError", message);
    return fmi2Error;
}

static Instance *valid(fmi2Component component) {
    Instance *c = (Instance *)component;
    return (c != NULL && c->magic == RG_MAGIC) ? c : NULL;
}

/* i with nodes[i] <= x <= nodes[i + 1] (i <= n - 2) and the weight of nodes[i + 1]; 0 where x lies beyond
   the nodes or is not a number (as Python's bisect_right - 1, clipped) */
static int cell(const double *nodes, int n, double x, int *i, double *w) {
    int lo = 0, hi = n;
    if (!(nodes[0] <= x && x <= nodes[n - 1])) return 0;
    if (n == 1) { *i = 0; *w = 0.0; return 1; }
    while (lo < hi) { /* the first node above x */
        int mid = lo + (hi - lo) / 2;
        if (x < nodes[mid]) hi = mid; else lo = mid + 1;
    }
    *i = lo - 1 < n - 2 ? lo - 1 : n - 2;
    *w = (x - nodes[*i]) / (nodes[*i + 1] - nodes[*i]);
    return 1;
}

static void evaluate(Instance *c) {
    const double torque = c->real[VR_TORQUE], speed = c->real[VR_SPEED], oil = c->real[VR_OIL];
    int i, j, k = 0;
    double wi, wj, wk = 0.0, total = 0.0, magnitude, eta = NAN;
    int d, e, power_sign;
    if (!isfinite(torque) || !isfinite(speed) || !isfinite(oil) || !cell(rg_speeds, RG_NS, speed, &i, &wi)
        || !cell(rg_torques, RG_NT, torque, &j, &wj) || (RG_NK > 1 && !cell(rg_temperatures, RG_NK, oil, &k, &wk))) {
        c->real[VR_LOSS] = c->real[VR_POWER] = c->real[VR_EFFICIENCY] = NAN;
        c->boolean[VB_INSIDE_TABLE] = c->boolean[VB_INSIDE_CALIBRATION] = c->boolean[VB_INSIDE_RATING] = fmi2False;
        return;
    }
    for (d = 0; d < 2; d++) {
        const double fi = d ? wi : 1.0 - wi;
        if (fi == 0.0) continue;
        for (e = 0; e < 2; e++) {
            const double fj = e ? wj : 1.0 - wj;
            size_t base;
            if (fj == 0.0) continue;
            base = ((size_t)(i + d) * RG_NT + (size_t)(j + e)) * RG_NK + (size_t)k;
            total += fi * fj * (c->loss[base] * (1.0 - wk) + (wk != 0.0 ? c->loss[base + 1] * wk : 0.0));
        }
    }
    c->real[VR_LOSS] = total;
    c->real[VR_POWER] = total * fabs(speed);
    c->boolean[VB_INSIDE_TABLE] = fmi2True;
    c->boolean[VB_INSIDE_CALIBRATION] = RG_CALIBRATED && fabs(speed) <= RG_SEEN_SPEED_RAD_S
        && fabs(torque) <= RG_SEEN_TORQUE_NM && RG_SEEN_OIL_LOW_C <= oil && oil <= RG_SEEN_OIL_HIGH_C;
    c->boolean[VB_INSIDE_RATING] = fabs(speed) <= RG_RATED_SPEED_RAD_S && fabs(torque) <= RG_RATED_TORQUE_NM;
    magnitude = fabs(torque);
    power_sign = speed > 0 ? (torque > 0) - (torque < 0) : (speed < 0 ? (torque < 0) - (torque > 0) : 0);
    if (magnitude >= RG_MIN_TORQUE_NM && fabs(speed) >= RG_MIN_SPEED_RAD_S && power_sign != 0) {
        eta = power_sign > 0 ? (magnitude - total) / magnitude : magnitude / (magnitude + total);
    }
    c->real[VR_EFFICIENCY] = eta > 0.0 ? eta : NAN;
}

static void start_values(Instance *c) {
    c->real[VR_TORQUE] = 0.0;
    c->real[VR_SPEED] = 0.0;
    c->real[VR_OIL] = RG_REFERENCE_TEMPERATURE_C;
    c->real[VR_ERROR_NM] = RG_INTERPOLATION_ERROR_NM;
    c->real[VR_ERROR_RELATIVE] = RG_INTERPOLATION_ERROR_RELATIVE;
    c->time = 0.0;
    evaluate(c);
}

/* the resources folder of a file: URI (file:///a/b, file:/a/b, file://localhost/a/b; %XX decoded) */
static int resource_path(const char *uri, const char *file, char *out, size_t size) {
    const char *p = uri;
    size_t n = 0;
    if (uri == NULL) return 0;
    if (strncmp(p, "file://localhost/", 17) == 0) p += 16;
    else if (strncmp(p, "file:///", 8) == 0) p += 7;
    else if (strncmp(p, "file:/", 6) == 0) p += 5;
    else return 0;
    while (*p != '\0' && n + 1 < size) {
        if (p[0] == '%' && p[1] != '\0' && p[2] != '\0') {
            char hex[3] = {p[1], p[2], '\0'};
            out[n++] = (char)strtol(hex, NULL, 16);
            p += 3;
        } else {
            out[n++] = *p++;
        }
    }
    if (n > 0 && out[n - 1] == '/') n--;
    return snprintf(out + n, size - n, "/%s", file) < (int)(size - n);
}

static int read_table(Instance *c, const char *resources) {
    char path[4096], message[4400];
    FILE *fh;
    size_t got;
    if (!resource_path(resources, "rollergear_loss.f64", path, sizeof path)) {
        snprintf(message, sizeof message, "the resource location is no file: URI (%.300s)",
                 resources ? resources : "none given");
        say(c, fmi2Error, "logStatusError", message);
        return 0;
    }
    fh = fopen(path, "rb");
    if (fh == NULL) {
        snprintf(message, sizeof message, "cannot open the loss table %s", path);
        say(c, fmi2Error, "logStatusError", message);
        return 0;
    }
    c->loss = (double *)malloc(RG_NODES * sizeof(double));
    got = c->loss != NULL ? fread(c->loss, sizeof(double), RG_NODES, fh) : 0;
    if (got == RG_NODES && fgetc(fh) != EOF) got = 0; /* longer than the grid: another table's */
    fclose(fh);
    if (got != RG_NODES) {
        snprintf(message, sizeof message, "the loss table %s does not hold the %lu values of the grid", path,
                 (unsigned long)RG_NODES);
        say(c, fmi2Error, "logStatusError", message);
        return 0;
    }
    return 1;
}

/* ------------------------------------------------------------------------------ FMI 2.0 common */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component component, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    Instance *c = valid(component);
    (void)nCategories;
    (void)categories;
    if (c == NULL) return fmi2Error;
    c->logging = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn) {
    Instance *c;
    (void)visible;
    if (functions == NULL || functions->logger == NULL || instanceName == NULL || instanceName[0] == '\0') {
        return NULL;
    }
    c = (Instance *)calloc(1, sizeof(Instance));
    if (c == NULL) return NULL;
    c->logger = functions->logger;
    c->environment = functions->componentEnvironment;
    c->logging = loggingOn ? 1 : 0;
    snprintf(c->name, sizeof c->name, "%s", instanceName);
    if (fmuType != fmi2CoSimulation) {
        say(c, fmi2Error, "logStatusError", "this unit is for co-simulation only");
    } else if (fmuGUID == NULL || strcmp(fmuGUID, RG_GUID) != 0) {
        say(c, fmi2Error, "logStatusError", "the GUID is not this unit's: its model description is another's");
    } else if (read_table(c, fmuResourceLocation)) {
        c->magic = RG_MAGIC;
        c->mode = INSTANTIATED;
        start_values(c);
        return c;
    }
    free(c->loss);
    free(c);
    return NULL;
}

void fmi2FreeInstance(fmi2Component component) {
    Instance *c = valid(component);
    if (c == NULL) return;
    c->magic = 0;
    free(c->loss);
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component component, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    Instance *c = valid(component);
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    if (c == NULL) return fmi2Error;
    if (c->mode != INSTANTIATED) return refuse(c, "fmi2SetupExperiment: only after fmi2Instantiate");
    c->time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component component) {
    Instance *c = valid(component);
    if (c == NULL) return fmi2Error;
    if (c->mode != INSTANTIATED) return refuse(c, "fmi2EnterInitializationMode: only after fmi2Instantiate");
    c->mode = INITIALIZING;
    evaluate(c);
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component component) {
    Instance *c = valid(component);
    if (c == NULL) return fmi2Error;
    if (c->mode != INITIALIZING) return refuse(c, "fmi2ExitInitializationMode: only in initialization mode");
    c->mode = STEPPING;
    evaluate(c);
    return fmi2OK;
}

fmi2Status fmi2Terminate(fmi2Component component) {
    Instance *c = valid(component);
    if (c == NULL) return fmi2Error;
    if (!(c->mode & (STEPPING | FAILED))) return refuse(c, "fmi2Terminate: only after initialization");
    c->mode = TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component component) {
    Instance *c = valid(component);
    if (c == NULL) return fmi2Error;
    c->mode = INSTANTIATED;
    start_values(c);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[]) {
    Instance *c = valid(component);
    size_t n;
    if (c == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || value == NULL)) return refuse(c, "fmi2GetReal: no value references");
    for (n = 0; n < nvr; n++) {
        if (vr[n] >= VR_REALS) return refuse(c, "fmi2GetReal: no such Real variable");
        value[n] = c->real[vr[n]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[]) {
    Instance *c = valid(component);
    size_t n;
    if (c == NULL) return fmi2Error;
    if (!(c->mode & (INSTANTIATED | INITIALIZING | STEPPING))) return refuse(c, "fmi2SetReal: not in this state");
    if (nvr > 0 && (vr == NULL || value == NULL)) return refuse(c, "fmi2SetReal: no value references");
    for (n = 0; n < nvr; n++) { /* all or nothing */
        if (vr[n] > VR_OIL) return refuse(c, "fmi2SetReal: only the inputs can be set (0, 1, 2)");
    }
    for (n = 0; n < nvr; n++) c->real[vr[n]] = value[n];
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[]) {
    Instance *c = valid(component);
    (void)vr;
    (void)value;
    if (c == NULL) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2GetInteger: the unit has no Integer variable");
}

fmi2Status fmi2SetInteger(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    Instance *c = valid(component);
    (void)vr;
    (void)value;
    if (c == NULL) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2SetInteger: the unit has no Integer variable");
}

fmi2Status fmi2GetBoolean(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[]) {
    Instance *c = valid(component);
    size_t n;
    if (c == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || value == NULL)) return refuse(c, "fmi2GetBoolean: no value references");
    for (n = 0; n < nvr; n++) {
        if (vr[n] >= VB_BOOLEANS) return refuse(c, "fmi2GetBoolean: no such Boolean variable");
        value[n] = c->boolean[vr[n]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    Instance *c = valid(component);
    (void)vr;
    (void)value;
    if (c == NULL) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2SetBoolean: the Booleans are outputs");
}

fmi2Status fmi2GetString(fmi2Component component, const fmi2ValueReference vr[], size_t nvr, fmi2String value[]) {
    Instance *c = valid(component);
    size_t n;
    if (c == NULL) return fmi2Error;
    if (nvr > 0 && (vr == NULL || value == NULL)) return refuse(c, "fmi2GetString: no value references");
    for (n = 0; n < nvr; n++) {
        if (vr[n] >= RG_N_STRINGS) return refuse(c, "fmi2GetString: no such String variable");
        value[n] = rg_strings[vr[n]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component component, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    Instance *c = valid(component);
    (void)vr;
    (void)value;
    if (c == NULL) return fmi2Error;
    return nvr == 0 ? fmi2OK : refuse(c, "fmi2SetString: the provenance is the table's, not settable");
}

/* no FMU state, no derivatives: declared so in the model description */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)s; return valid(c) ? refuse(valid(c), "no FMU state") : fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)s; return valid(c) ? refuse(valid(c), "no FMU state") : fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)s; return valid(c) ? refuse(valid(c), "no FMU state") : fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) {
    (void)s; (void)n; return valid(c) ? refuse(valid(c), "no FMU state") : fmi2Error;
}
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) {
    (void)s; (void)b; (void)n; return valid(c) ? refuse(valid(c), "no FMU state") : fmi2Error;
}
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) {
    (void)s; (void)b; (void)n; return valid(c) ? refuse(valid(c), "no FMU state") : fmi2Error;
}
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk, const fmi2Real du[], fmi2Real dk[]) {
    (void)u; (void)nu; (void)k; (void)nk; (void)du; (void)dk;
    return valid(c) ? refuse(valid(c), "no directional derivatives") : fmi2Error;
}

/* ------------------------------------------------------------------------------ co-simulation */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return valid(c) ? refuse(valid(c), "no input derivatives") : fmi2Error;
}
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    (void)vr; (void)nvr; (void)order; (void)value;
    return valid(c) ? refuse(valid(c), "no output derivatives") : fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component component, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    Instance *c = valid(component);
    (void)noSetFMUStatePriorToCurrentPoint;
    if (c == NULL) return fmi2Error;
    if (c->mode != STEPPING) return refuse(c, "fmi2DoStep: only after fmi2ExitInitializationMode");
    if (!(communicationStepSize >= 0.0)) return refuse(c, "fmi2DoStep: a step size below 0");
    evaluate(c);
    c->time = currentCommunicationPoint + communicationStepSize;
    return fmi2OK;
}

fmi2Status fmi2CancelStep(fmi2Component c) { return valid(c) ? refuse(valid(c), "no asynchronous step to cancel") : fmi2Error; }

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { (void)s; (void)v; return valid(c) ? fmi2Discard : fmi2Error; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    Instance *i = valid(c);
    if (i == NULL) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = i->time;
    return fmi2OK;
}
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { (void)s; (void)v; return valid(c) ? fmi2Discard : fmi2Error; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) { (void)s; (void)v; return valid(c) ? fmi2Discard : fmi2Error; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { (void)s; (void)v; return valid(c) ? fmi2Discard : fmi2Error; }
