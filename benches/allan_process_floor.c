// The floor under the whole `imulab allan x.npy --rate 150 --kind oadev` process on a machine:
// a process that starts, maps and populates the .npy (3.24 M float64, 26 MB), integrates it
// into a fresh huge-page-advised buffer (the phase: one pass over the samples into new
// memory) and exits, computing no deviation at all. docs/bench/allan.md compares it with ours.
//   gcc -O2 -o /tmp/floor benches/allan_process_floor.c && perf stat -r 30 /tmp/floor x.npy o.txt
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>
int main(int argc, char **argv) {
  int fd = open(argv[1], O_RDONLY);
  struct stat st; fstat(fd, &st);
  const char *map = mmap(0, st.st_size, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd, 0);
  size_t n = (st.st_size - 128) / 8;
  const double *y = (const double *)(map + 128);
  double *x = NULL;
  posix_memalign((void **)&x, 1 << 21, (n + 1) * 8);
  madvise(x, (n + 1) * 8, MADV_HUGEPAGE);
  double s = 0; x[0] = 0;
  for (size_t i = 0; i < n; i++) { s += y[i]; x[i + 1] = s; }
  if (argc > 2) { FILE *f = fopen(argv[2], "w"); fprintf(f, "%g\n", x[n]); fclose(f); }
  return 0;
}
