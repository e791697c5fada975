/* The exported controller at the DAQ period against a plant in another process: a real-time driver
 * example (written by `mitigate export` as rt/driver.c; rt/rt_config.h names the library).
 *
 * Every period k, released at r_k = r_0 + k P on CLOCK_MONOTONIC (clock_nanosleep, TIMER_ABSTIME):
 *   the library's step on sample k (received during the last period) -> the commands;
 *   one datagram with the commands to the plant, one datagram back with sample k + 1.
 * The period's deadline is r_{k+1}: a period whose step and exchange end later has MISSED it (counted,
 * with its lateness); the next period is then released at the next boundary still ahead (the release
 * slots passed over are counted as skipped), so a late period never causes a burst.  The plant steps
 * once per command (lockstep): a missed deadline shows in the statistics, not in the physics.  On a
 * rig, replace exchange() by the DAQ's read and write.
 *
 * Wire format (host byte order; both ends on one machine): a 24-byte header {magic "SSRT", kind,
 * seq (u64), n, 0} then n doubles (an error: n bytes of text).  hello: {N_IN, N_CMD, DAQ period} ->
 * sample 0; command seq k: the commands of sample k -> sample k + 1 {t, in[0..N_IN-1]}; bye.
 */
#define _GNU_SOURCE
#include <arpa/inet.h>
#include <errno.h>
#include <math.h>
#include <netinet/in.h>
#include <sched.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include "rt_config.h"
#include LIB_HEADER

#define MAGIC 0x54525353u
enum { MSG_HELLO = 1, MSG_COMMAND = 2, MSG_BYE = 3, MSG_SAMPLE = 4, MSG_ERROR = 5 };

typedef struct {
    uint32_t magic, kind;
    uint64_t seq;
    uint32_t n, reserved;
} head;

#define MAXD (N_IN + 160)   /* a sample, or an error's text */
typedef struct {
    head h;
    double d[MAXD];
} packet;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static struct timespec to_timespec(double t) {
    struct timespec ts;
    ts.tv_sec = (time_t)floor(t);
    ts.tv_nsec = (long)((t - floor(t)) * 1e9);
    if (ts.tv_nsec >= 1000000000L) { ts.tv_sec++; ts.tv_nsec -= 1000000000L; }
    return ts;
}

static int send_msg(int fd, uint32_t kind, uint64_t seq, const double* d, uint32_t n) {
    packet p;
    p.h.magic = MAGIC; p.h.kind = kind; p.h.seq = seq; p.h.n = n; p.h.reserved = 0;
    if (n) memcpy(p.d, d, n * sizeof(double));
    return send(fd, &p, sizeof(head) + n * sizeof(double), 0) < 0 ? -1 : 0;
}

/* wait for sample `seq` (stale datagrams are dropped): 0 ok, -1 timeout or socket error, -2 the
 * plant's error (printed) */
static int recv_sample(int fd, uint64_t seq, double* t, double* in) {
    packet p;
    for (;;) {
        ssize_t r = recv(fd, &p, sizeof(p), 0);
        if (r < 0) return -1;
        if (r < (ssize_t)sizeof(head) || p.h.magic != MAGIC) continue;
        if (p.h.kind == MSG_ERROR) {
            int n = (int)(r - (ssize_t)sizeof(head));
            fprintf(stderr, "the plant refused: %.*s\n", n, (const char*)p.d);
            return -2;
        }
        if (p.h.kind != MSG_SAMPLE || p.h.seq != seq || p.h.n != 1 + N_IN ||
            r != (ssize_t)(sizeof(head) + (1 + N_IN) * sizeof(double))) continue;
        *t = p.d[0];
        memcpy(in, p.d + 1, N_IN * sizeof(double));
        return 0;
    }
}

static int cmp(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

/* quantile q of v[0..n-1] (sorted in place): the smallest value with at least q n values at or below */
static double quantile(double* v, long n, double q) {
    long i;
    if (n <= 0) return NAN;
    qsort(v, (size_t)n, sizeof(double), cmp);
    i = (long)ceil(q * (double)n) - 1;
    return v[i < 0 ? 0 : i >= n ? n - 1 : i];
}

static void usage(const char* me) {
    fprintf(stderr,
            "usage: %s [--duration S] [--port P] [--host ADDR] [--period S] [--priority N] [--timeout S]\n"
            "          [--log FILE] [--param NAME=VALUE ...]\n"
            "  runs the exported controller every DAQ period (%g s) for --duration seconds of samples (default 10)\n"
            "  against the plant server at ADDR:P (default 127.0.0.1:47100; python -m mitigate.export.plant_server);\n"
            "  --priority N: SCHED_FIFO priority N and locked memory (0, the default: normal scheduling);\n"
            "  --period S: another period than the DAQ's (a headroom test; the plant still steps one DAQ period);\n"
            "  --log FILE: one CSV row per period (times in microseconds), written after the run;\n"
            "  --param NAME=VALUE: a runtime parameter (README.md's params[] names), no rebuild.\n", me, RT_DT);
}

int main(int argc, char** argv) {
    double duration = 10.0, period = RT_DT, timeout = 2.0, params[N_PAR > 0 ? N_PAR : 1];
    const char *host = "127.0.0.1", *log_path = NULL;
    int port = 47100, priority = 0, fd, i, j, fifo = 0, status_n[4] = {0, 0, 0, 0};
    long n, k, missed = 0, skipped = 0;
    double t, in[N_IN], out[N_OUT], r0, release, max_late = 0.0;
    double *step_us, *exch_us, *wake_us, *late_us, *rel_us, *sorted;
    struct sockaddr_in addr;
    struct timeval tv;
    LIB_TYPE* s;

    for (i = 0; i < N_PAR; i++) params[i] = LIB(param_default)(i);
    for (i = 1; i < argc; i++) {
        const char* a = argv[i];
        const char* v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "--help") || !strcmp(a, "-h")) { usage(argv[0]); return 0; }
        if (!v) { fprintf(stderr, "%s: %s needs a value\n", argv[0], a); return 2; }
        if (!strcmp(a, "--duration")) duration = atof(v);
        else if (!strcmp(a, "--port")) port = atoi(v);
        else if (!strcmp(a, "--host")) host = v;
        else if (!strcmp(a, "--period")) period = atof(v);
        else if (!strcmp(a, "--priority")) priority = atoi(v);
        else if (!strcmp(a, "--timeout")) timeout = atof(v);
        else if (!strcmp(a, "--log")) log_path = v;
        else if (!strcmp(a, "--param")) {
            const char* eq = strchr(v, '=');
            int found = -1;
            char* end;
            double x;
            for (j = 0; eq && j < N_PAR; j++)
                if (strlen(LIB(param_name)(j)) == (size_t)(eq - v) && !strncmp(LIB(param_name)(j), v, (size_t)(eq - v)))
                    found = j;
            if (found < 0) { fprintf(stderr, "%s: --param %s: no such parameter (README.md lists them)\n", argv[0], v); return 2; }
            x = eq ? strtod(eq + 1, &end) : NAN;
            if (!eq || end == eq + 1 || *end || !isfinite(x)) {
                fprintf(stderr, "%s: --param %s: expected NAME=<finite number>\n", argv[0], v);
                return 2;
            }
            params[found] = x;
        } else { fprintf(stderr, "%s: unknown option %s (--help)\n", argv[0], a); return 2; }
        i++;
    }
    if (!(duration > 0) || !(period > 0) || !(timeout > 0) || port <= 0 || port > 65535 || priority < 0 || priority > 99) {
        fprintf(stderr, "%s: --duration, --period and --timeout must be > 0 s, --port 1..65535, --priority 0..99\n", argv[0]);
        return 2;
    }
    n = lround(duration / RT_DT);
    if (n < 1) n = 1;
    step_us = malloc((size_t)n * sizeof(double));
    exch_us = malloc((size_t)n * sizeof(double));
    wake_us = malloc((size_t)n * sizeof(double));
    late_us = malloc((size_t)n * sizeof(double));
    rel_us = malloc((size_t)n * sizeof(double));
    sorted = malloc((size_t)n * sizeof(double));
    if (!step_us || !exch_us || !wake_us || !late_us || !rel_us || !sorted) { fprintf(stderr, "%s: out of memory\n", argv[0]); return 1; }
    s = LIB(create)(params);
    if (!s) { fprintf(stderr, "%s: create() refused the parameters\n", argv[0]); return 2; }

    fd = socket(AF_INET, SOCK_DGRAM, 0);
    memset(&addr, 0, sizeof(addr));
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t)port);
    if (fd < 0 || inet_pton(AF_INET, host, &addr.sin_addr) != 1 || connect(fd, (struct sockaddr*)&addr, sizeof(addr)) < 0) {
        fprintf(stderr, "%s: cannot reach %s:%d\n", argv[0], host, port);
        return 1;
    }
    tv.tv_sec = (time_t)timeout;
    tv.tv_usec = (suseconds_t)((timeout - floor(timeout)) * 1e6);
    setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
    {
        double hello[3] = {N_IN, N_CMD, RT_DT};
        int r;
        if (send_msg(fd, MSG_HELLO, 0, hello, 3) < 0 || (r = recv_sample(fd, 0, &t, in)) == -1) {
            fprintf(stderr, "%s: no answer from the plant at %s:%d within %g s (is the plant server running?)\n",
                    argv[0], host, port, timeout);
            return 1;
        }
        if (r < 0) return 1;
    }
    if (priority > 0) {
        struct sched_param sp;
        sp.sched_priority = priority;
        if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0)
            fprintf(stderr, "%s: mlockall failed (%s); continuing\n", argv[0], strerror(errno));
        fifo = sched_setscheduler(0, SCHED_FIFO, &sp) == 0;
        if (!fifo) fprintf(stderr, "%s: SCHED_FIFO %d refused (%s); normal scheduling\n", argv[0], priority, strerror(errno));
    }

    r0 = now() + period;
    release = r0;
    for (k = 0; k < n; k++) {
        struct timespec ts = to_timespec(release);
        double woke, stepped, done, deadline, next;
        int st, r;
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {}
        woke = now();
        st = LIB(step)(s, t, in, out);
        stepped = now();
        if (st >= 0 && st < 4) status_n[st]++;
        if (send_msg(fd, MSG_COMMAND, (uint64_t)k, out, N_CMD) < 0 || (r = recv_sample(fd, (uint64_t)k + 1, &t, in)) == -1) {
            fprintf(stderr, "%s: the plant did not answer sample %ld within %g s\n", argv[0], k + 1, timeout);
            return 1;
        }
        if (r < 0) return 1;
        done = now();
        deadline = release + period;
        rel_us[k] = 1e6 * (release - r0);
        wake_us[k] = 1e6 * (woke - release);
        step_us[k] = 1e6 * (stepped - woke);
        exch_us[k] = 1e6 * (done - stepped);
        late_us[k] = 1e6 * (done - deadline);
        if (done > deadline) {
            missed++;
            if (done - deadline > max_late) max_late = done - deadline;
        }
        next = deadline;
        if (done > next) {   /* released late: resume at the next boundary still ahead */
            long m = (long)ceil((done - next) / period);
            next += (double)m * period;
            skipped += m;
        }
        release = next;
    }
    send_msg(fd, MSG_BYE, (uint64_t)n, NULL, 0);
    close(fd);
    LIB(destroy)(s);

    if (log_path) {
        FILE* f = fopen(log_path, "w");
        if (!f) { fprintf(stderr, "%s: cannot write %s\n", argv[0], log_path); return 1; }
        fprintf(f, "k,release_us,wake_us,step_us,exchange_us,lateness_us\n");
        for (k = 0; k < n; k++)
            fprintf(f, "%ld,%.3f,%.3f,%.3f,%.3f,%.3f\n", k, rel_us[k], wake_us[k], step_us[k],
                    exch_us[k], late_us[k]);
        fclose(f);
    }
    printf("%s: %ld periods of %g ms against the plant at %s:%d, %s\n", argv[0], n, 1e3 * period, host, port,
           fifo ? "SCHED_FIFO" : "normal scheduling");
    {
        double sm, sp, sx, em, ep, wp;
        memcpy(sorted, step_us, (size_t)n * sizeof(double));
        sm = quantile(sorted, n, 0.5); sp = quantile(sorted, n, 0.99); sx = sorted[n - 1];
        memcpy(sorted, exch_us, (size_t)n * sizeof(double));
        em = quantile(sorted, n, 0.5); ep = quantile(sorted, n, 0.99);
        memcpy(sorted, wake_us, (size_t)n * sizeof(double));
        wp = quantile(sorted, n, 0.99);
        printf("deadlines: %ld of %ld missed (%.2f %%), max lateness %.3f ms, %ld release slot(s) skipped\n", missed, n,
               100.0 * (double)missed / (double)n, 1e3 * max_late, skipped);
        printf("step: median %.1f us, p99 %.1f us, max %.1f us; exchange: median %.1f us, p99 %.1f us; "
               "wake-up latency p99 %.1f us\n", sm, sp, sx, em, ep, wp);
        printf("statuses: ok %d hold %d fallback %d failed %d\n", status_n[0], status_n[1], status_n[2], status_n[3]);
        printf("periods %ld missed %ld max_lateness_us %.3f skipped %ld step_median_us %.3f step_p99_us %.3f "
               "step_max_us %.3f exchange_median_us %.3f exchange_p99_us %.3f wake_p99_us %.3f ok %d hold %d "
               "fallback %d failed %d\n", n, missed, 1e6 * max_late, skipped, sm, sp, sx, em, ep, wp, status_n[0],
               status_n[1], status_n[2], status_n[3]);
    }
    free(step_us); free(exch_us); free(wake_us); free(late_us); free(rel_us); free(sorted);
    return 0;
}
