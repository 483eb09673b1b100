// A model of the two-rank step under a noisy neighbour, without the physics: each step
// is `phases` phases of calibrated arithmetic, and each phase ends by sending one
// number to the other rank. Phase p may start its last part only once the other rank's
// message of phase p - lookahead has arrived; the first `interior` fraction of it
// needs no message (a step that works on its interior while the halo travels).
// lookahead 1 with interior 0 is today's bulk-synchronous step. A wait either spins in
// MPI_Wait or, with nap_us > 0, tests and sleeps nap_us between tests.
//
//   mpicc -O2 -o noisy_model scripts/noisy_model.c
//   mpirun -n 2 --bind-to core --map-by core ./noisy_model \
//       STEPS PHASES PHASE_US SHARE1 LOOKAHEAD INTERIOR NAP_US
//
// PHASE_US is one rank's phase on a quiet core at an even split; SHARE1 is rank 1's
// share of the work. Prints the wall time of the steps (the slower rank's).
#include <mpi.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define MAX_LOOKAHEAD 16

static volatile double sink;

static void work(long units) {
    double a = 1.0;
    for (long i = 0; i < units; i++)
        for (int k = 0; k < 64; k++) a = a * 0.9999999 + 1e-9;
    sink = a;
}

static void wait_for(MPI_Request *r, long nap_us) {
    if (nap_us > 0) {
        struct timespec ts = {0, nap_us * 1000L};
        int done = 0;
        for (;;) {
            MPI_Test(r, &done, MPI_STATUS_IGNORE);
            if (done) return;
            nanosleep(&ts, NULL);
        }
    }
    MPI_Wait(r, MPI_STATUS_IGNORE);
}

int main(int argc, char **argv) {
    MPI_Init(&argc, &argv);
    int rank, size;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    if (argc != 8 || size != 2) {
        if (rank == 0)
            fprintf(stderr, "usage: mpirun -n 2 %s STEPS PHASES PHASE_US SHARE1 LOOKAHEAD "
                            "INTERIOR NAP_US\n", argv[0]);
        MPI_Finalize();
        return 2;
    }
    int steps = atoi(argv[1]), phases = atoi(argv[2]);
    double phase_us = atof(argv[3]), share1 = atof(argv[4]);
    int lookahead = atoi(argv[5]);
    double interior = atof(argv[6]);
    long nap_us = atol(argv[7]);
    if (lookahead < 1 || lookahead > MAX_LOOKAHEAD || interior < 0 || interior > 1) {
        if (rank == 0) fprintf(stderr, "LOOKAHEAD is 1..%d, INTERIOR 0..1\n", MAX_LOOKAHEAD);
        MPI_Finalize();
        return 2;
    }
    // Work units per microsecond, timed on rank 0 (the quiet core) and shared.
    double per_us = 0;
    if (rank == 0) {
        work(20000);
        double t = MPI_Wtime();
        work(200000);
        per_us = 200000 / ((MPI_Wtime() - t) * 1e6);
    }
    MPI_Bcast(&per_us, 1, MPI_DOUBLE, 0, MPI_COMM_WORLD);
    double mine = rank == 1 ? share1 : 1.0 - share1;
    long units = (long)(2.0 * phase_us * mine * per_us);
    long inner = (long)(units * interior), outer = units - inner;
    int other = 1 - rank;
    MPI_Request rq[MAX_LOOKAHEAD], sq[MAX_LOOKAHEAD];
    double in[MAX_LOOKAHEAD], out[MAX_LOOKAHEAD];
    MPI_Barrier(MPI_COMM_WORLD);
    double t0 = MPI_Wtime();
    // The messages of phases -lookahead .. -1, so that the first phases may start.
    for (int k = 0; k < lookahead; k++) {
        out[k] = k - lookahead;
        MPI_Irecv(&in[k], 1, MPI_DOUBLE, other, 0, MPI_COMM_WORLD, &rq[k]);
        MPI_Isend(&out[k], 1, MPI_DOUBLE, other, 0, MPI_COMM_WORLD, &sq[k]);
    }
    for (long p = 0; p < (long)steps * phases; p++) {
        int k = (int)(p % lookahead);
        work(inner);
        wait_for(&rq[k], nap_us);
        MPI_Wait(&sq[k], MPI_STATUS_IGNORE);
        work(outer);
        out[k] = (double)p;
        MPI_Irecv(&in[k], 1, MPI_DOUBLE, other, 0, MPI_COMM_WORLD, &rq[k]);
        MPI_Isend(&out[k], 1, MPI_DOUBLE, other, 0, MPI_COMM_WORLD, &sq[k]);
    }
    MPI_Waitall(lookahead, rq, MPI_STATUSES_IGNORE);
    MPI_Waitall(lookahead, sq, MPI_STATUSES_IGNORE);
    double t = MPI_Wtime() - t0, slowest;
    MPI_Reduce(&t, &slowest, 1, MPI_DOUBLE, MPI_MAX, 0, MPI_COMM_WORLD);
    if (rank == 0) printf("%.3f\n", slowest);
    MPI_Finalize();
    return 0;
}
