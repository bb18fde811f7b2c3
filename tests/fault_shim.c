// An LD_PRELOAD library for fault tests: makes writes to files under one directory fail,
// as a full disk or a file system remounted read-only would, while a control file exists.
//
//   FLEXID_FAULT_DIR=/tmp/x/db       writes to files whose path starts with this fail ...
//   FLEXID_FAULT_CONTROL=/tmp/x/full ... while this file exists. Its first word picks the
//                                    error: "ENOSPC" (also when empty), "EROFS" or "EIO".
//
// Intercepted: write, pwrite, pwrite64, writev, pwritev, fallocate, posix_fallocate (and
// their 64-bit names). Reads, opens and memory-mapped writes (SQLite's -shm) go through.
// While the control file is absent the only cost is one access() per write call.
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

// The error to fail with for a write to fd, or 0 to let it through.
static int FaultFor(int fd) {
  const char* control = getenv("FLEXID_FAULT_CONTROL");
  const char* dir = getenv("FLEXID_FAULT_DIR");
  if (!control || !dir || !*dir || access(control, F_OK) != 0) return 0;
  char link[64], target[4096];
  snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
  const ssize_t n = readlink(link, target, sizeof target - 1);
  if (n <= 0) return 0;
  target[n] = '\0';
  if (strncmp(target, dir, strlen(dir)) != 0) return 0;
  char word[16] = {0};
  FILE* f = fopen(control, "r");
  if (f) {
    if (fscanf(f, "%15s", word) != 1) word[0] = '\0';
    fclose(f);
  }
  if (strcmp(word, "EROFS") == 0) return EROFS;
  if (strcmp(word, "EIO") == 0) return EIO;
  return ENOSPC;
}

#define REAL(name, type) ((type)dlsym(RTLD_NEXT, name))
#define FAIL_IF_FAULT(fd)       \
  do {                          \
    const int e = FaultFor(fd); \
    if (e) {                    \
      errno = e;                \
      return -1;                \
    }                           \
  } while (0)

ssize_t write(int fd, const void* buf, size_t count) {
  FAIL_IF_FAULT(fd);
  return REAL("write", ssize_t(*)(int, const void*, size_t))(fd, buf, count);
}
ssize_t pwrite(int fd, const void* buf, size_t count, off_t offset) {
  FAIL_IF_FAULT(fd);
  return REAL("pwrite", ssize_t(*)(int, const void*, size_t, off_t))(fd, buf, count, offset);
}
ssize_t pwrite64(int fd, const void* buf, size_t count, off64_t offset) {
  FAIL_IF_FAULT(fd);
  return REAL("pwrite64", ssize_t(*)(int, const void*, size_t, off64_t))(fd, buf, count, offset);
}
ssize_t writev(int fd, const struct iovec* iov, int iovcnt) {
  FAIL_IF_FAULT(fd);
  return REAL("writev", ssize_t(*)(int, const struct iovec*, int))(fd, iov, iovcnt);
}
ssize_t pwritev(int fd, const struct iovec* iov, int iovcnt, off_t offset) {
  FAIL_IF_FAULT(fd);
  return REAL("pwritev", ssize_t(*)(int, const struct iovec*, int, off_t))(fd, iov, iovcnt, offset);
}
int fallocate(int fd, int mode, off_t offset, off_t len) {
  FAIL_IF_FAULT(fd);
  return REAL("fallocate", int (*)(int, int, off_t, off_t))(fd, mode, offset, len);
}
int fallocate64(int fd, int mode, off64_t offset, off64_t len) {
  FAIL_IF_FAULT(fd);
  return REAL("fallocate64", int (*)(int, int, off64_t, off64_t))(fd, mode, offset, len);
}
// posix_fallocate returns the error instead of setting errno.
int posix_fallocate(int fd, off_t offset, off_t len) {
  const int e = FaultFor(fd);
  if (e) return e;
  return REAL("posix_fallocate", int (*)(int, off_t, off_t))(fd, offset, len);
}
int posix_fallocate64(int fd, off64_t offset, off64_t len) {
  const int e = FaultFor(fd);
  if (e) return e;
  return REAL("posix_fallocate64", int (*)(int, off64_t, off64_t))(fd, offset, len);
}
