/* Flight-computer example: the generated WingRock SKI filter over a recording.
 *
 *   flight_computer [-g SIGMA] [recording.csv]      (stdin when no file is given)
 *
 * Reads the CSV one line at a time. Its header names the columns: t, every model
 * input and output (for WingRock `t,delta,phi`), in any order; other columns are
 * ignored. An empty or `nan` measurement cell means "not measured". The filter
 * starts from the first roll reading (wingrock_ski_reset); -g sets the innovation
 * gate in its settings (default: the generated one, 5 sigma). Rows are expected
 * every WINGROCK_SKI_DT seconds: a longer step is filled with unmeasured samples
 * (at most gap_limit), as a fixed-rate task would run. Prints `t,<augmented state
 * names>,code` and then, per row, t, the posterior mean and the step's code
 * (enum skigen_status); gated readings, stuck sensors and restarts are also
 * reported on stderr. Exit status 0, or 1 on a usage, I/O or format error.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "wingrock_ski.h"

#define MAX_LINE 4096
#define MAX_COLS 256
#define NU WINGROCK_SKI_NU
#define NY WINGROCK_SKI_NY

typedef wingrock_ski_real real;

/* Split a line in place at commas; returns the number of cells. */
static int split(char* line, char** cells)
{
    int n = 0;
    line[strcspn(line, "\r\n")] = '\0';
    cells[n++] = line;
    for (; *line != '\0' && n < MAX_COLS; ++line) {
        if (*line == ',') {
            *line = '\0';
            cells[n++] = line + 1;
        }
    }
    return n;
}

static int find(char** cells, int n, const char* name)
{
    int i;
    for (i = 0; i < n; ++i) if (strcmp(cells[i], name) == 0) return i;
    return -1;
}

/* Parse a whole cell as a number; an empty cell gives NaN when allow_empty. */
static int number(const char* cell, int allow_empty, double* out)
{
    char* end;
    if (*cell == '\0') {
        *out = NAN;
        return allow_empty;
    }
    *out = strtod(cell, &end);
    return end != cell && *end == '\0';
}

static const char* const WORDS[] = {"ok", "measurement skipped", "bad input", "numerical failure",
                                    "outlier rejected", "sensor stuck", "states restarted", "bad settings"};

/* One step, with its code reported on stderr unless OK or a plain missing measurement. */
static int step(wingrock_ski_state* st, const real* u, const real* y, long row)
{
    int code = wingrock_ski_step(st, u, y);
    if (code != SKIGEN_OK && code != SKIGEN_MEASUREMENT_SKIPPED)
        fprintf(stderr, "row %ld: %s (code %d)\n", row, code >= 0 && code <= SKIGEN_BAD_SETTINGS ? WORDS[code] : "?", code);
    return code;
}

int main(int argc, char** argv)
{
    static wingrock_ski_state st; /* static storage: no stack or heap needed for the state */
    char line[MAX_LINE];
    char* cells[MAX_COLS];
    int col_t, col_u[NU > 0 ? NU : 1], col_y[NY > 0 ? NY : 1];
    real u[NU > 0 ? NU : 1], y[NY > 0 ? NY : 1], gap[NY > 0 ? NY : 1];
    long row = 1;
    int i, n, arg = 1, started = 0;
    double t_last = 0, gate = -1;
    FILE* in = stdin;

    if (argc > 2 && strcmp(argv[1], "-g") == 0) {
        if (!number(argv[2], 0, &gate) || !(gate >= 0)) {
            fprintf(stderr, "-g: expected a gate in standard deviations (0: off), got '%s'\n", argv[2]);
            return 1;
        }
        arg = 3;
    }
    if (argc > arg + 1) {
        fprintf(stderr, "usage: %s [-g SIGMA] [recording.csv]\n", argv[0]);
        return 1;
    }
    if (argc == arg + 1 && (in = fopen(argv[arg], "r")) == NULL) {
        perror(argv[arg]);
        return 1;
    }
    for (i = 0; i < NY; ++i) gap[i] = (real)NAN;
    if (fgets(line, sizeof line, in) == NULL) {
        fprintf(stderr, "empty recording\n");
        return 1;
    }
    n = split(line, cells);
    col_t = find(cells, n, "t");
    for (i = 0; i < NU; ++i) col_u[i] = find(cells, n, wingrock_ski_input_names[i]);
    for (i = 0; i < NY; ++i) col_y[i] = find(cells, n, wingrock_ski_output_names[i]);
    if (col_t < 0) {
        fprintf(stderr, "header lacks column 't'\n");
        return 1;
    }
    for (i = 0; i < NU; ++i) if (col_u[i] < 0) {
        fprintf(stderr, "header lacks input column '%s'\n", wingrock_ski_input_names[i]);
        return 1;
    }
    for (i = 0; i < NY; ++i) if (col_y[i] < 0) {
        fprintf(stderr, "header lacks output column '%s'\n", wingrock_ski_output_names[i]);
        return 1;
    }

    printf("t");
    for (i = 0; i < WINGROCK_SKI_N; ++i) printf(",%s", wingrock_ski_state_names[i]);
    printf(",code\n");

    wingrock_ski_init(&st);
    if (gate >= 0) st.settings.gate = (real)gate;
    if (wingrock_ski_settings_check(&st.settings) != 0) {   /* e.g. -g inf: refused by every step */
        fprintf(stderr, "invalid settings (field %d of wingrock_ski_settings_check)\n",
                wingrock_ski_settings_check(&st.settings));
        return 1;
    }
    while (fgets(line, sizeof line, in) != NULL) {
        double t = 0, v = 0;
        int ok, code;
        ++row;
        n = split(line, cells);
        if (n == 1 && cells[0][0] == '\0') continue; /* blank line */
        ok = col_t < n && number(cells[col_t], 0, &t) && isfinite(t);
        for (i = 0; ok && i < NU; ++i) {
            ok = col_u[i] < n && number(cells[col_u[i]], 0, &v);
            u[i] = (real)v;
        }
        for (i = 0; ok && i < NY; ++i) {
            ok = col_y[i] < n && number(cells[col_y[i]], 1, &v);
            y[i] = (real)v;
        }
        if (!ok) {
            fprintf(stderr, "row %ld: malformed line\n", row);
            return 1;
        }
        if (!started && isfinite(y[WINGROCK_SKI_Y_PHI])) {
            /* Start at the first roll reading, the rest as declared. */
            real z0[WINGROCK_SKI_N];
            for (i = 0; i < WINGROCK_SKI_N; ++i) z0[i] = st.z[i];
            z0[WINGROCK_SKI_Z_THETA] = y[WINGROCK_SKI_Y_PHI];
            wingrock_ski_reset(&st, z0, NULL);
            started = 1;
        } else if (started) {
            /* Samples missing from the recording: predict through them with this row's input, up
             * to gap_limit of them (after a longer hole a reading the gate rejects restarts the states). */
            double missing = floor((t - t_last) / WINGROCK_SKI_DT + 0.5) - 1;
            long k;
            for (k = 0; k < missing && k < st.settings.gap_limit; ++k) step(&st, u, gap, row);
        }
        t_last = t;
        code = step(&st, u, y, row);
        printf("%.17g", t);
        for (i = 0; i < WINGROCK_SKI_N; ++i) printf(",%.17g", (double)st.z_post[i]);
        printf(",%d\n", code);
    }
    if (in != stdin) fclose(in);
    return 0;
}
