/*
 * A stand-in for OpenHaptics' libHD, compiled by the tests (gcc -shared -fPIC) so that the `touch` backend's
 * ctypes binding is exercised for real: same symbols, same calling conventions, same rules (state is read
 * only inside hdBeginFrame/hdEndFrame while the scheduler runs; errors are reported through hdGetError).
 *
 * It serves a scripted trajectory. LIBHD_STANDIN_SCRIPT names a text file with one frame per line:
 *     <device> x y z g0 g1 g2 buttons
 * where <device> is the name given to hdInitDevice ("Left", "Right") or "default" for HD_DEFAULT_DEVICE.
 * Every hdBeginFrame of a device advances it to its next frame; after the last one the stylus rests there.
 *
 * Optional:
 *   LIBHD_STANDIN_UNPLUG_AFTER=N   after N frames of a device, hdBeginFrame fails with HD_COMM_ERROR
 *                                  (the cable was pulled);
 *   LIBHD_STANDIN_LOG=path         appends one line per lifecycle call (init, start, stop, disable) so tests
 *                                  can check the order of calls.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef unsigned int HHD;
typedef unsigned int HDenum;
typedef unsigned int HDerror;
typedef unsigned int HDCallbackCode;
typedef HDCallbackCode (*HDSchedulerCallback)(void *);
typedef struct { HDerror errorCode; int internalErrorCode; HHD hHD; } HDErrorInfo;

#define HD_SUCCESS 0x0000
#define HD_INVALID_ENUM 0x0100
#define HD_ILLEGAL_BEGIN 0x0204
#define HD_COMM_ERROR 0x0302
#define HD_DEVICE_FAULT 0x0305
#define HD_INVALID_HANDLE 0xFFFFFFFFu
#define HD_CURRENT_BUTTONS 0x2000
#define HD_CURRENT_POSITION 0x2050
#define HD_CURRENT_GIMBAL_ANGLES 0x2150
#define HD_CALLBACK_DONE 0

#define MAX_DEVICES 4
#define MAX_NAME 32

typedef struct {
    char name[MAX_NAME];
    int enabled;
    double *frames;   /* n_frames x 7: x y z g0 g1 g2 buttons */
    int n_frames;
    int next;         /* index of the frame served by the next hdBeginFrame */
    int served;       /* frames served so far */
} Device;

static Device devices[MAX_DEVICES];
static int n_devices = 0;
static HHD current = HD_INVALID_HANDLE;
static int in_frame = 0;
static int scheduler_running = 0;
static HDErrorInfo last_error = {HD_SUCCESS, 0, HD_INVALID_HANDLE};

static void set_error(HDerror code, HHD h) {
    if (last_error.errorCode == HD_SUCCESS) {
        last_error.errorCode = code;
        last_error.internalErrorCode = (int)code + 1000;
        last_error.hHD = h;
    }
}

static void log_call(const char *what, const char *arg) {
    const char *path = getenv("LIBHD_STANDIN_LOG");
    if (!path) return;
    FILE *f = fopen(path, "a");
    if (!f) return;
    fprintf(f, "%s %s\n", what, arg ? arg : "");
    fclose(f);
}

static void load_script(Device *d) {
    const char *path = getenv("LIBHD_STANDIN_SCRIPT");
    d->frames = NULL;
    d->n_frames = 0;
    if (!path) return;
    FILE *f = fopen(path, "r");
    if (!f) return;
    int capacity = 0;
    char name[MAX_NAME];
    double v[7];
    while (fscanf(f, "%31s %lf %lf %lf %lf %lf %lf %lf", name, &v[0], &v[1], &v[2], &v[3], &v[4], &v[5], &v[6]) == 8) {
        if (strcmp(name, d->name) != 0) continue;
        if (d->n_frames == capacity) {
            capacity = capacity ? 2 * capacity : 64;
            d->frames = realloc(d->frames, sizeof(double) * 7 * capacity);
        }
        memcpy(d->frames + 7 * d->n_frames, v, sizeof v);
        d->n_frames++;
    }
    fclose(f);
}

static Device *device(HHD h) {
    if (h >= (HHD)n_devices || !devices[h].enabled) return NULL;
    return &devices[h];
}

HHD hdInitDevice(const char *config_name) {
    const char *name = config_name ? config_name : "default";
    log_call("init", name);
    int slot = 0;   /* reuse the handle of a disabled device, as libHD does */
    while (slot < n_devices && devices[slot].enabled) slot++;
    if (slot == MAX_DEVICES || scheduler_running) {
        set_error(HD_DEVICE_FAULT, HD_INVALID_HANDLE);
        return HD_INVALID_HANDLE;
    }
    Device *d = &devices[slot];
    memset(d, 0, sizeof *d);
    strncpy(d->name, name, MAX_NAME - 1);
    load_script(d);
    if (d->n_frames == 0) {   /* no frames scripted for this name: no such device is plugged in */
        set_error(HD_COMM_ERROR, HD_INVALID_HANDLE);
        return HD_INVALID_HANDLE;
    }
    d->enabled = 1;
    current = (HHD)slot;
    if (slot == n_devices) n_devices++;
    return (HHD)slot;
}

void hdDisableDevice(HHD h) {
    Device *d = device(h);
    log_call("disable", d ? d->name : "?");
    if (d) { d->enabled = 0; free(d->frames); d->frames = NULL; }
}

void hdMakeCurrentDevice(HHD h) {
    if (!device(h)) { set_error(HD_INVALID_ENUM, h); return; }
    current = h;
}

HHD hdGetCurrentDevice(void) { return current; }

void hdStartScheduler(void) { log_call("start", NULL); scheduler_running = 1; }
void hdStopScheduler(void) { log_call("stop", NULL); scheduler_running = 0; }

void hdBeginFrame(HHD h) {
    Device *d = device(h);
    if (!d || !scheduler_running || in_frame) { set_error(HD_ILLEGAL_BEGIN, h); return; }
    const char *unplug = getenv("LIBHD_STANDIN_UNPLUG_AFTER");
    if (unplug && d->served >= atoi(unplug)) { set_error(HD_COMM_ERROR, h); return; }
    current = h;
    in_frame = 1;
}

void hdEndFrame(HHD h) {
    Device *d = device(h);
    if (!d || !in_frame) return;
    in_frame = 0;
    d->served++;
    if (d->next < d->n_frames - 1) d->next++;
}

void hdGetDoublev(HDenum what, double *out) {
    Device *d = device(current);
    if (!d || !in_frame) { set_error(HD_ILLEGAL_BEGIN, current); return; }
    const double *f = d->frames + 7 * d->next;
    if (what == HD_CURRENT_POSITION) memcpy(out, f, 3 * sizeof(double));
    else if (what == HD_CURRENT_GIMBAL_ANGLES) memcpy(out, f + 3, 3 * sizeof(double));
    else set_error(HD_INVALID_ENUM, current);
}

void hdGetIntegerv(HDenum what, int *out) {
    Device *d = device(current);
    if (!d || !in_frame) { set_error(HD_ILLEGAL_BEGIN, current); return; }
    if (what == HD_CURRENT_BUTTONS) *out = (int)d->frames[7 * d->next + 6];
    else set_error(HD_INVALID_ENUM, current);
}

void hdScheduleSynchronous(HDSchedulerCallback callback, void *user_data, unsigned short priority) {
    (void)priority;
    if (!scheduler_running) { set_error(HD_ILLEGAL_BEGIN, current); return; }
    callback(user_data);
}

HDErrorInfo hdGetError(void) {
    HDErrorInfo e = last_error;
    last_error.errorCode = HD_SUCCESS;
    last_error.internalErrorCode = 0;
    return e;
}

const char *hdGetErrorString(HDerror code) {
    switch (code) {
    case HD_SUCCESS: return "success";
    case HD_INVALID_ENUM: return "invalid enum";
    case HD_ILLEGAL_BEGIN: return "illegal begin (no scheduler or nested frame)";
    case HD_COMM_ERROR: return "communication error";
    case HD_DEVICE_FAULT: return "device fault";
    default: return "unknown error";
    }
}
