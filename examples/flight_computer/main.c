/* Flight-computer example: the generated WingRock SKI filter over a recording.
 *
 *   flight_computer [recording.csv]      (stdin when no file is given)
 *
 * Reads the CSV one line at a time. Its header names the columns: t, every model
 * input and output (for WingRock `t,delta,phi`), in any order; other columns are
 * ignored. An empty or `nan` measurement cell means "not measured". Prints
 * `t,<augmented state names>` and then, per sample, t and the posterior mean.
 * Non-OK step codes are reported on stderr. Exit status 0, or 1 on a usage,
 * I/O or format error.
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

int main(int argc, char** argv)
{
    static wingrock_ski_state st; /* static storage: no stack or heap needed for the state */
    char line[MAX_LINE];
    char* cells[MAX_COLS];
    int col_t, col_u[NU > 0 ? NU : 1], col_y[NY > 0 ? NY : 1];
    real u[NU > 0 ? NU : 1], y[NY > 0 ? NY : 1];
    long row = 1;
    int i, n;
    FILE* in = stdin;

    if (argc > 2) {
        fprintf(stderr, "usage: %s [recording.csv]\n", argv[0]);
        return 1;
    }
    if (argc == 2 && (in = fopen(argv[1], "r")) == NULL) {
        perror(argv[1]);
        return 1;
    }
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
    printf("\n");

    wingrock_ski_init(&st);
    while (fgets(line, sizeof line, in) != NULL) {
        double t = 0, v = 0;
        int ok, code;
        ++row;
        n = split(line, cells);
        if (n == 1 && cells[0][0] == '\0') continue; /* blank line */
        ok = col_t < n && number(cells[col_t], 0, &t);
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
        code = wingrock_ski_step(&st, u, y);
        if (code == SKIGEN_BAD_INPUT || code == SKIGEN_NUMERICAL_FAILURE)
            fprintf(stderr, "row %ld: step rejected (code %d)\n", row, code);
        printf("%.17g", t);
        for (i = 0; i < WINGROCK_SKI_N; ++i) printf(",%.17g", (double)st.z_post[i]);
        printf("\n");
    }
    if (in != stdin) fclose(in);
    return 0;
}
