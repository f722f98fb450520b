/* Fault injection for bench/faults.py at the lowest layer: while the file named by
   $FLEETGATE_EIO_TRIGGER exists, fsync and fdatasync fail with EIO (a disk that cannot
   sync); otherwise they are libc's. Built with: cc -shared -fPIC -o eio_shim.so eio_shim.c -ldl
   and loaded with LD_PRELOAD into the gateway process only. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <stdlib.h>
#include <unistd.h>

static int failing(void) {
    const char *trigger = getenv("FLEETGATE_EIO_TRIGGER");
    return trigger != NULL && access(trigger, F_OK) == 0;
}

int fsync(int fd) {
    static int (*real)(int) = NULL;
    if (failing()) { errno = EIO; return -1; }
    if (real == NULL) real = (int (*)(int))dlsym(RTLD_NEXT, "fsync");
    return real(fd);
}

int fdatasync(int fd) {
    static int (*real)(int) = NULL;
    if (failing()) { errno = EIO; return -1; }
    if (real == NULL) real = (int (*)(int))dlsym(RTLD_NEXT, "fdatasync");
    return real(fd);
}
