/* I/O errors for the fault-injection test (tests/server/faults.rs), loaded into the server
 * with LD_PRELOAD: while the file named by MESHWIKI_EIO_TRIGGER exists, every write and sync
 * of a file under MESHWIKI_EIO_DIR fails with EIO, as a failing disk's would (SQLite's
 * journal and database pages, uploads, attachments, the search index). Reads, and files
 * elsewhere (logs, sockets), are untouched. Interposes the libc entry points the server's
 * writers reach: Rust's std and SQLite's unix VFS call them through the dynamic linker. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/uio.h>
#include <unistd.h>

static int failing(int fd) {
    const char *trigger = getenv("MESHWIKI_EIO_TRIGGER");
    const char *dir = getenv("MESHWIKI_EIO_DIR");
    if (trigger == NULL || dir == NULL) {
        return 0;
    }
    struct stat st;
    if (stat(trigger, &st) != 0) {
        return 0;
    }
    char link[64];
    char path[4096];
    snprintf(link, sizeof link, "/proc/self/fd/%d", fd);
    ssize_t n = readlink(link, path, sizeof path - 1);
    if (n <= 0) {
        return 0;
    }
    path[n] = '\0';
    size_t len = strlen(dir);
    return strncmp(path, dir, len) == 0 && (path[len] == '/' || path[len] == '\0');
}

#define REAL(name)                                   \
    static __typeof__(name) *real = NULL;            \
    if (real == NULL) {                              \
        real = (__typeof__(name) *)dlsym(RTLD_NEXT, #name); \
    }

ssize_t write(int fd, const void *buf, size_t count) {
    REAL(write);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd, buf, count);
}

ssize_t pwrite(int fd, const void *buf, size_t count, off_t offset) {
    REAL(pwrite);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd, buf, count, offset);
}

ssize_t pwrite64(int fd, const void *buf, size_t count, off64_t offset) {
    REAL(pwrite64);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd, buf, count, offset);
}

ssize_t writev(int fd, const struct iovec *iov, int iovcnt) {
    REAL(writev);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd, iov, iovcnt);
}

ssize_t pwritev(int fd, const struct iovec *iov, int iovcnt, off_t offset) {
    REAL(pwritev);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd, iov, iovcnt, offset);
}

int fsync(int fd) {
    REAL(fsync);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd);
}

int fdatasync(int fd) {
    REAL(fdatasync);
    if (failing(fd)) {
        errno = EIO;
        return -1;
    }
    return real(fd);
}
