/*
 * tactile-rig V4L2 preload: UVC cameras emulated at the system-call boundary.
 *
 * Loaded with LD_PRELOAD into a process whose environment names a registry directory
 * (TACTILE_RIG_V4L2_DIR). The registry holds a tree mirroring the paths a real camera owns:
 *
 *   $DIR/root/dev/videoN            a Unix (SOCK_SEQPACKET) socket: the device server of that node
 *   $DIR/root/dev/v4l/by-id/...     symlinks, as udev makes them
 *   $DIR/root/dev/char/81:N         symlink
 *   $DIR/root/sys/...               the node's sysfs entries (class/video4linux, dev/char, devices)
 *
 * For an absolute path under /dev/video, /dev/v4l, /dev/char/81:, /sys/class/video4linux,
 * /sys/dev/char/81: or /sys/devices/tactile-rig, the library looks the path up in that tree
 * when it is used (so a process sees cameras started after it) and, when present, uses the tree's
 * entry instead (a real directory of the same name wins, so real cameras stay visible). A path
 * that resolves to a socket under $DIR/root/dev is the device node: stat() calls it a character
 * device 81:N, open() connects to the server and returns a descriptor whose readiness the server
 * drives (an eventfd), and ioctl/mmap/munmap/poll/select/read/write/close on that descriptor go to
 * the server. A listing of /dev (opendir/readdir) ends with the registry's video nodes and its v4l
 * directory, where the real /dev has no entry of that name. Every other path and descriptor goes
 * straight to the C library.
 *
 * The wire protocol is tactile_rig/mocks/v4l2/protocol.py (one request message, one reply message,
 * descriptors passed with SCM_RIGHTS). Arguments are copied in and out of the caller's memory with
 * process_vm_readv/process_vm_writev on our own process, so a NULL or unmapped pointer gives EFAULT
 * as the kernel's copy_from_user/copy_to_user do (a pipe is the fallback where those calls are not
 * allowed).
 */
#define _GNU_SOURCE
#include <dirent.h>
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <linux/close_range.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <sys/sysmacros.h>
#include <sys/uio.h>
#include <sys/xattr.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>

#define EXPORT __attribute__((visibility("default")))
#define ENV_DIR "TACTILE_RIG_V4L2_DIR"
#define VIDEO_MAJOR 81
#define MAX_FDS 65536
#define MAX_MAPS 256

/* -- protocol (keep in step with protocol.py) ------------------------------------------------ */
enum { OP_OPEN = 1, OP_ATTACH = 2, OP_IOCTL = 3, OP_MMAP = 4, OP_MUNMAP = 5, OP_POLL = 6, OP_READ = 7 };
struct req { uint32_t op; int32_t arg0; uint64_t cmd, arg1, arg2; uint32_t len, len2; };
struct rep { int32_t result; uint32_t len, len2, nfds; uint64_t aux; };

/* -- the C library's own functions ----------------------------------------------------------- */
static void *resolve(void **slot, const char *name)
{
    void *p = __atomic_load_n(slot, __ATOMIC_ACQUIRE);
    if (!p) {
        p = dlsym(RTLD_NEXT, name);
        __atomic_store_n(slot, p, __ATOMIC_RELEASE);
    }
    return p;
}
#define REAL(name) ((__typeof__(real_##name))resolve((void **)&real_##name, #name))
static int (*real_open)(const char *, int, ...);
static int (*real_open64)(const char *, int, ...);
static int (*real_openat)(int, const char *, int, ...);
static int (*real_openat64)(int, const char *, int, ...);
static int (*real___open_2)(const char *, int);
static int (*real___open64_2)(const char *, int);
static int (*real___openat_2)(int, const char *, int);
static int (*real___openat64_2)(int, const char *, int);
static FILE *(*real_fopen)(const char *, const char *);
static FILE *(*real_fopen64)(const char *, const char *);
static DIR *(*real_opendir)(const char *);
static struct dirent *(*real_readdir)(DIR *);
static struct dirent64 *(*real_readdir64)(DIR *);
static void (*real_rewinddir)(DIR *);
static int (*real_closedir)(DIR *);
static int (*real_access)(const char *, int);
static int (*real_eaccess)(const char *, int);
static int (*real_euidaccess)(const char *, int);
static int (*real_faccessat)(int, const char *, int, int);
static ssize_t (*real_readlink)(const char *, char *, size_t);
static ssize_t (*real_readlinkat)(int, const char *, char *, size_t);
static int (*real_stat)(const char *, struct stat *);
static int (*real_stat64)(const char *, struct stat64 *);
static int (*real_lstat)(const char *, struct stat *);
static int (*real_lstat64)(const char *, struct stat64 *);
static int (*real_fstat)(int, struct stat *);
static int (*real_fstat64)(int, struct stat64 *);
static int (*real_fstatat)(int, const char *, struct stat *, int);
static int (*real_fstatat64)(int, const char *, struct stat64 *, int);
static int (*real___xstat)(int, const char *, struct stat *);
static int (*real___xstat64)(int, const char *, struct stat64 *);
static int (*real___lxstat)(int, const char *, struct stat *);
static int (*real___lxstat64)(int, const char *, struct stat64 *);
static int (*real___fxstat)(int, int, struct stat *);
static int (*real___fxstat64)(int, int, struct stat64 *);
static int (*real___fxstatat)(int, int, const char *, struct stat *, int);
static int (*real___fxstatat64)(int, int, const char *, struct stat64 *, int);
static int (*real_statx)(int, const char *, int, unsigned int, struct statx *);
static int (*real_close)(int);
static int (*real_ioctl)(int, unsigned long, ...);
static void *(*real_mmap)(void *, size_t, int, int, int, off_t);
static void *(*real_mmap64)(void *, size_t, int, int, int, off64_t);
static int (*real_munmap)(void *, size_t);
static int (*real_poll)(struct pollfd *, nfds_t, int);
static int (*real___poll_chk)(struct pollfd *, nfds_t, int, size_t);
static int (*real_ppoll)(struct pollfd *, nfds_t, const struct timespec *, const sigset_t *);
static int (*real___ppoll_chk)(struct pollfd *, nfds_t, const struct timespec *, const sigset_t *, size_t);
static int (*real_select)(int, fd_set *, fd_set *, fd_set *, struct timeval *);
static int (*real_pselect)(int, fd_set *, fd_set *, fd_set *, const struct timespec *, const sigset_t *);
static ssize_t (*real_read)(int, void *, size_t);
static ssize_t (*real___read_chk)(int, void *, size_t, size_t);
static ssize_t (*real_write)(int, const void *, size_t);
static int (*real_dup)(int);
static int (*real_dup2)(int, int);
static int (*real_dup3)(int, int, int);
static int (*real_fcntl)(int, int, ...);
static int (*real_fcntl64)(int, int, ...);
static long (*real_syscall)(long, ...);

/* -- registry ---------------------------------------------------------------------------------- */
static char registry[PATH_MAX];      /* the registry directory, canonical; "" = nothing emulated */
static char dev_prefix[PATH_MAX];    /* registry + "/root/dev/video" */

__attribute__((constructor)) static void init(void)
{
    const char *dir = getenv(ENV_DIR);
    char canon[PATH_MAX];

    if (!dir || !*dir)
        return;
    /* The directory may not exist yet (a server started later creates it): keep the name as given. */
    if (!realpath(dir, canon))
        snprintf(canon, sizeof canon, "%s", dir);
    snprintf(registry, sizeof registry, "%s", canon);
    snprintf(dev_prefix, sizeof dev_prefix, "%s/root/dev/video", registry);
}

static int raw_stat(const char *path, struct stat *st, int follow)
{
    return (int)REAL(syscall)(SYS_newfstatat, AT_FDCWD, path, st, follow ? 0 : AT_SYMLINK_NOFOLLOW);
}

static int candidate(const char *p)
{
    static const char *const prefixes[] = {
        "/dev/video", "/dev/v4l", "/dev/char/81:", "/sys/class/video4linux", "/sys/dev/char/81:",
        "/sys/devices/tactile-rig", NULL,
    };
    if (!registry[0] || !p || p[0] != '/')
        return 0;
    for (int i = 0; prefixes[i]; i++)
        if (strncmp(p, prefixes[i], strlen(prefixes[i])) == 0)
            return 1;
    return 0;
}

/* The registry's stand-in for an absolute path, in out[PATH_MAX]; 0 if the path is not emulated. */
static int redirect(const char *path, char *out)
{
    struct stat st;
    int saved = errno, hit = 0;

    if (candidate(path) && snprintf(out, PATH_MAX, "%s/root%s", registry, path) < PATH_MAX &&
        raw_stat(out, &st, 0) == 0) {
        hit = 1;
        if (S_ISDIR(st.st_mode) && raw_stat(path, &st, 0) == 0)
            hit = 0; /* a real directory of that name wins */
    }
    errno = saved;
    return hit;
}

/* Is this path (after redirection) one of the emulated device nodes? Fills the server socket path. */
static int device_node(const char *path, char *sock, int *minor)
{
    char r[PATH_MAX];
    struct stat st;
    int saved = errno, ok = 0;
    size_t n = strlen(dev_prefix);

    if (redirect(path, r) && raw_stat(r, &st, 1) == 0 && S_ISSOCK(st.st_mode) && realpath(r, sock) &&
        strncmp(sock, dev_prefix, n) == 0 && sock[n] >= '0' && sock[n] <= '9') {
        char *end;
        long m = strtol(sock + n, &end, 10);
        if (*end == '\0' && m >= 0 && m < (1 << 20)) {
            *minor = (int)m;
            ok = 1;
        }
    }
    errno = saved;
    return ok;
}

/* -- emulated descriptors ------------------------------------------------------------------------- */
struct conn {
    int sock;            /* to the device server */
    int efd_pri;         /* readable while an event is pending (or the device is gone) */
    int efd_wait;        /* readable while a blocking DQBUF would return */
    int minor;
    int refs;            /* descriptors in the table that refer to this open file */
    int maps;            /* live mmap()s of its buffers */
    int closed;          /* the last descriptor is closed: the server has released the file handle */
    pid_t pid;           /* the process whose socket `sock` is (a forked child attaches anew) */
    uint64_t fh;         /* the server's file handle id */
    pthread_mutex_t lock;
    char sockpath[PATH_MAX];
};

struct mapping { void *addr; size_t len; uint64_t offset; struct conn *c; };

static pthread_mutex_t table_lock = PTHREAD_MUTEX_INITIALIZER;
static struct conn **table;          /* fd -> conn, allocated at the first emulated open */
static int n_emulated;               /* descriptors in the table: 0 keeps every fast path fast */
static struct mapping maps[MAX_MAPS];
static int n_maps;

static struct conn *lookup(int fd)
{
    struct conn **t = __atomic_load_n(&table, __ATOMIC_ACQUIRE);
    if (!t || fd < 0 || fd >= MAX_FDS || !__atomic_load_n(&n_emulated, __ATOMIC_RELAXED))
        return NULL;
    return __atomic_load_n(&t[fd], __ATOMIC_ACQUIRE);
}

static void conn_free_if_unused(struct conn *c)
{
    /* table_lock held */
    if (c->refs == 0 && c->maps == 0) {
        pthread_mutex_destroy(&c->lock);
        free(c);
    }
}

static void table_set(int fd, struct conn *c)
{
    /* table_lock held; fd < MAX_FDS checked by the caller */
    struct conn *old = table[fd];
    if (old) {
        old->refs--;
        n_emulated--;
        if (old->refs == 0) {
            REAL(close)(old->sock);
            REAL(close)(old->efd_pri);
            REAL(close)(old->efd_wait);
            old->closed = 1;
        }
    }
    if (c) {
        c->refs++;
        n_emulated++;
    }
    __atomic_store_n(&table[fd], c, __ATOMIC_RELEASE);
    if (old)
        conn_free_if_unused(old);
}

static int ensure_table(void)
{
    if (table)
        return 0;
    struct conn **t = calloc(MAX_FDS, sizeof *t);
    if (!t)
        return -1;
    __atomic_store_n(&table, t, __ATOMIC_RELEASE);
    return 0;
}

/* -- messages --------------------------------------------------------------------------------- */
static int connect_server(const char *sockpath)
{
    struct sockaddr_un sa = { .sun_family = AF_UNIX };
    int s;

    if (strlen(sockpath) >= sizeof sa.sun_path) {
        errno = ENAMETOOLONG;
        return -1;
    }
    strcpy(sa.sun_path, sockpath);
    s = socket(AF_UNIX, SOCK_SEQPACKET | SOCK_CLOEXEC, 0);
    if (s < 0)
        return -1;
    if (connect(s, (struct sockaddr *)&sa, sizeof sa) < 0) {
        int e = errno;
        REAL(close)(s);
        /* A node whose server is gone is an unplugged device. */
        errno = (e == ECONNREFUSED || e == ENOENT) ? ENODEV : e;
        return -1;
    }
    return s;
}

/* One request, one reply. Returns the reply's result (>= 0, or -errno), fills fds (up to 3). */
static int exchange_sock(int sock, const struct req *q, const void *p1, const void *p2, struct rep *r,
                         void *o1, size_t o1len, void *o2, size_t o2len, int *fds, int maxfds)
{
    struct iovec iov[3] = {
        { (void *)q, sizeof *q }, { (void *)p1, q->len }, { (void *)p2, q->len2 },
    };
    struct msghdr mh = { .msg_iov = iov, .msg_iovlen = 3 };
    ssize_t n;
    union { char buf[CMSG_SPACE(3 * sizeof(int))]; struct cmsghdr align; } u;
    struct iovec riov[3] = { { r, sizeof *r }, { o1, o1len }, { o2, o2len } };
    struct msghdr rm = { .msg_iov = riov, .msg_iovlen = 3, .msg_control = u.buf, .msg_controllen = sizeof u.buf };

    for (int i = 0; i < maxfds; i++)
        fds[i] = -1;
    do
        n = sendmsg(sock, &mh, MSG_NOSIGNAL);
    while (n < 0 && errno == EINTR);
    if (n < 0)
        return -ENODEV; /* the server is gone: the device was pulled */
    do
        n = recvmsg(sock, &rm, MSG_CMSG_CLOEXEC);
    while (n < 0 && errno == EINTR);
    if (n < (ssize_t)sizeof *r || (rm.msg_flags & MSG_TRUNC))
        return -ENODEV;
    for (struct cmsghdr *cm = CMSG_FIRSTHDR(&rm); cm; cm = CMSG_NXTHDR(&rm, cm)) {
        if (cm->cmsg_level == SOL_SOCKET && cm->cmsg_type == SCM_RIGHTS) {
            int k = (int)((cm->cmsg_len - CMSG_LEN(0)) / sizeof(int));
            int *in = (int *)CMSG_DATA(cm);
            for (int i = 0; i < k; i++) {
                if (i < maxfds)
                    fds[i] = in[i];
                else
                    REAL(close)(in[i]);
            }
        }
    }
    return r->result;
}

static int reattach(struct conn *c)
{
    /* c->lock held. After fork() the child must not share the parent's socket: it connects anew
     * and joins the same server-side file handle, as a forked process shares the open file. */
    struct req q = { .op = OP_ATTACH, .arg1 = c->fh };
    struct rep r;
    int fds[3];
    int s = connect_server(c->sockpath);
    if (s < 0)
        return -ENODEV;
    int res = exchange_sock(s, &q, NULL, NULL, &r, NULL, 0, NULL, 0, fds, 3);
    for (int i = 0; i < 3; i++)
        if (fds[i] >= 0)
            REAL(close)(fds[i]);
    if (res < 0) {
        REAL(close)(s);
        return res;
    }
    REAL(close)(c->sock);
    c->sock = s;
    c->pid = getpid();
    return 0;
}

static int exchange(struct conn *c, const struct req *q, const void *p1, const void *p2, struct rep *r,
                    void *o1, size_t o1len, void *o2, size_t o2len, int *fds, int maxfds)
{
    int res;

    pthread_mutex_lock(&c->lock);
    if (c->closed)
        res = -EBADF;
    else if (c->pid != getpid() && (res = reattach(c)) < 0)
        ;
    else
        res = exchange_sock(c->sock, q, p1, p2, r, o1, o1len, o2, o2len, fds, maxfds);
    pthread_mutex_unlock(&c->lock);
    return res;
}

static int simple(struct conn *c, uint32_t op, int32_t arg0, uint64_t cmd, uint64_t arg1, uint64_t arg2)
{
    struct req q = { .op = op, .arg0 = arg0, .cmd = cmd, .arg1 = arg1, .arg2 = arg2 };
    struct rep r;
    int fds[3];
    int res = exchange(c, &q, NULL, NULL, &r, NULL, 0, NULL, 0, fds, 3);
    for (int i = 0; i < 3; i++)
        if (fds[i] >= 0)
            REAL(close)(fds[i]);
    return res;
}

/* -- user memory, with the kernel's EFAULT -------------------------------------------------------- */
static pthread_mutex_t probe_lock = PTHREAD_MUTEX_INITIALIZER;
static int use_pipe = 0;

static int pipe_copy(void *dst, const void *src, size_t n, int to_user)
{
    /* Fallback where process_vm_* is not permitted: the kernel reads src (write to a pipe) and
     * writes dst (read from the pipe), failing with EFAULT on a bad user pointer. */
    static int p[2] = { -1, -1 };
    int ok = 0;
    pthread_mutex_lock(&probe_lock);
    if (p[0] < 0 && pipe2(p, O_CLOEXEC) < 0) {
        pthread_mutex_unlock(&probe_lock);
        return -1;
    }
    while (n > 0) {
        size_t k = n > 4096 ? 4096 : n;
        if (REAL(write)(p[1], src, k) != (ssize_t)k) {
            ok = -1;
            break;
        }
        if (REAL(read)(p[0], dst, k) != (ssize_t)k) {
            char sink[4096];
            REAL(read)(p[0], sink, k); /* drain what the bad destination left */
            ok = -1;
            break;
        }
        (void)to_user;
        dst = (char *)dst + k;
        src = (const char *)src + k;
        n -= k;
    }
    pthread_mutex_unlock(&probe_lock);
    return ok;
}

static int copy_from_user(void *dst, const void *user, size_t n)
{
    if (n == 0)
        return 0;
    if (!user)
        return -1;
    if (!__atomic_load_n(&use_pipe, __ATOMIC_RELAXED)) {
        struct iovec local = { dst, n }, remote = { (void *)user, n };
        ssize_t k = process_vm_readv(getpid(), &local, 1, &remote, 1, 0);
        if (k == (ssize_t)n)
            return 0;
        if (k < 0 && (errno == ENOSYS || errno == EPERM))
            __atomic_store_n(&use_pipe, 1, __ATOMIC_RELAXED);
        else
            return -1;
    }
    return pipe_copy(dst, user, n, 0);
}

static int copy_to_user(void *user, const void *src, size_t n)
{
    if (n == 0)
        return 0;
    if (!user)
        return -1;
    if (!__atomic_load_n(&use_pipe, __ATOMIC_RELAXED)) {
        struct iovec local = { (void *)src, n }, remote = { user, n };
        ssize_t k = process_vm_writev(getpid(), &local, 1, &remote, 1, 0);
        if (k == (ssize_t)n)
            return 0;
        if (k < 0 && (errno == ENOSYS || errno == EPERM))
            __atomic_store_n(&use_pipe, 1, __ATOMIC_RELAXED);
        else
            return -1;
    }
    return pipe_copy(user, src, n, 1);
}

/* -- open ---------------------------------------------------------------------------------------- */
static int emu_open(const char *sockpath, int minor, int flags)
{
    struct req q = { .op = OP_OPEN, .arg0 = flags };
    struct rep r;
    int fds[3], s, res;
    struct conn *c;

    s = connect_server(sockpath);
    if (s < 0)
        return -1;
    res = exchange_sock(s, &q, NULL, NULL, &r, NULL, 0, NULL, 0, fds, 3);
    if (res < 0 || fds[0] < 0 || fds[1] < 0 || fds[2] < 0) {
        for (int i = 0; i < 3; i++)
            if (fds[i] >= 0)
                REAL(close)(fds[i]);
        REAL(close)(s);
        errno = res < 0 ? -res : EIO;
        return -1;
    }
    /* fds[0] becomes the caller's descriptor: its readiness is the device's poll state. */
    if (!(flags & O_CLOEXEC))
        REAL(fcntl)(fds[0], F_SETFD, 0);
    /* The server made the eventfd non-blocking; the open file's status is the caller's. */
    REAL(fcntl)(fds[0], F_SETFL, flags & O_NONBLOCK);
    c = calloc(1, sizeof *c);
    pthread_mutex_lock(&table_lock);
    if (!c || fds[0] >= MAX_FDS || ensure_table() < 0) {
        pthread_mutex_unlock(&table_lock);
        free(c);
        for (int i = 0; i < 3; i++)
            REAL(close)(fds[i]);
        REAL(close)(s);
        errno = EMFILE;
        return -1;
    }
    c->sock = s;
    c->efd_pri = fds[1];
    c->efd_wait = fds[2];
    c->minor = minor;
    c->pid = getpid();
    c->fh = r.aux;
    pthread_mutex_init(&c->lock, NULL);
    snprintf(c->sockpath, sizeof c->sockpath, "%s", sockpath);
    table_set(fds[0], c);
    pthread_mutex_unlock(&table_lock);
    return fds[0];
}

static int want_mode(int flags)
{
    return (flags & O_CREAT) || (flags & O_TMPFILE) == O_TMPFILE;
}

#define OPEN_BODY(realcall)                                                                         \
    char r[PATH_MAX], sock[PATH_MAX];                                                               \
    int minor;                                                                                      \
    mode_t mode = 0;                                                                                \
    if (want_mode(flags)) {                                                                         \
        va_list ap;                                                                                 \
        va_start(ap, flags);                                                                        \
        mode = va_arg(ap, mode_t);                                                                  \
        va_end(ap);                                                                                 \
    }                                                                                               \
    if (device_node(path, sock, &minor))                                                            \
        return emu_open(sock, minor, flags);                                                        \
    if (redirect(path, r))                                                                          \
        path = r;                                                                                   \
    return realcall;

EXPORT int open(const char *path, int flags, ...) { OPEN_BODY(REAL(open)(path, flags, mode)) }
EXPORT int open64(const char *path, int flags, ...) { OPEN_BODY(REAL(open64)(path, flags, mode)) }

#define OPENAT_BODY(realcall)                                                                       \
    char r[PATH_MAX], sock[PATH_MAX];                                                               \
    int minor;                                                                                      \
    mode_t mode = 0;                                                                                \
    if (want_mode(flags)) {                                                                         \
        va_list ap;                                                                                 \
        va_start(ap, flags);                                                                        \
        mode = va_arg(ap, mode_t);                                                                  \
        va_end(ap);                                                                                 \
    }                                                                                               \
    if (path && path[0] == '/') {                                                                   \
        if (device_node(path, sock, &minor))                                                        \
            return emu_open(sock, minor, flags);                                                    \
        if (redirect(path, r))                                                                      \
            path = r;                                                                               \
    }                                                                                               \
    return realcall;

EXPORT int openat(int dirfd, const char *path, int flags, ...) { OPENAT_BODY(REAL(openat)(dirfd, path, flags, mode)) }
EXPORT int openat64(int dirfd, const char *path, int flags, ...)
{
    OPENAT_BODY(REAL(openat64)(dirfd, path, flags, mode))
}

EXPORT int __open_2(const char *path, int flags)
{
    char r[PATH_MAX], sock[PATH_MAX];
    int minor;
    if (device_node(path, sock, &minor))
        return emu_open(sock, minor, flags);
    return REAL(__open_2)(redirect(path, r) ? r : path, flags);
}

EXPORT int __open64_2(const char *path, int flags)
{
    char r[PATH_MAX], sock[PATH_MAX];
    int minor;
    if (device_node(path, sock, &minor))
        return emu_open(sock, minor, flags);
    return REAL(__open64_2)(redirect(path, r) ? r : path, flags);
}

EXPORT int __openat_2(int dirfd, const char *path, int flags)
{
    char r[PATH_MAX], sock[PATH_MAX];
    int minor;
    if (path && path[0] == '/' && device_node(path, sock, &minor))
        return emu_open(sock, minor, flags);
    return REAL(__openat_2)(dirfd, path && path[0] == '/' && redirect(path, r) ? r : path, flags);
}

EXPORT int __openat64_2(int dirfd, const char *path, int flags)
{
    char r[PATH_MAX], sock[PATH_MAX];
    int minor;
    if (path && path[0] == '/' && device_node(path, sock, &minor))
        return emu_open(sock, minor, flags);
    return REAL(__openat64_2)(dirfd, path && path[0] == '/' && redirect(path, r) ? r : path, flags);
}

EXPORT FILE *fopen(const char *path, const char *mode)
{
    char r[PATH_MAX];
    return REAL(fopen)(redirect(path, r) ? r : path, mode);
}

EXPORT FILE *fopen64(const char *path, const char *mode)
{
    char r[PATH_MAX];
    return REAL(fopen64)(redirect(path, r) ? r : path, mode);
}

/* -- the /dev listing --------------------------------------------------------------------------
 * A directory stream opened on /dev is given, after the real entries, the registry's video nodes
 * (as character devices) and its v4l directory, unless the real /dev has an entry of that name. */
#define MAX_LISTINGS 8
#define MAX_EXTRA 64
struct listing {
    DIR *dir;
    int n, next;
    char names[MAX_EXTRA][32];
    unsigned char types[MAX_EXTRA];
    struct dirent ent;
    struct dirent64 ent64;
};
static struct listing listings[MAX_LISTINGS];
static int listings_open; /* how many slots are in use: 0 keeps readdir() on its fast path */
static pthread_mutex_t listing_lock = PTHREAD_MUTEX_INITIALIZER;

static int is_dev_dir(const char *path)
{
    return path && (strcmp(path, "/dev") == 0 || strcmp(path, "/dev/") == 0);
}

static void add_listing(DIR *d)
{
    char dir[PATH_MAX], real_path[PATH_MAX];
    struct listing *l = NULL;
    struct dirent *e;
    struct stat st;
    DIR *reg;
    int saved = errno;

    if (snprintf(dir, sizeof dir, "%s/root/dev", registry) >= (int)sizeof dir || !(reg = REAL(opendir)(dir)))
        goto out;
    pthread_mutex_lock(&listing_lock);
    for (int i = 0; i < MAX_LISTINGS; i++)
        if (!listings[i].dir) {
            l = &listings[i];
            break;
        }
    if (l) {
        memset(l, 0, sizeof *l);
        while ((e = REAL(readdir)(reg)) && l->n < MAX_EXTRA) {
            int video = strncmp(e->d_name, "video", 5) == 0, v4l = strcmp(e->d_name, "v4l") == 0;
            if ((!video && !v4l) || strlen(e->d_name) >= sizeof l->names[0])
                continue;
            snprintf(real_path, sizeof real_path, "/dev/%s", e->d_name);
            if (raw_stat(real_path, &st, 0) == 0)
                continue; /* the real /dev has it */
            snprintf(l->names[l->n], sizeof l->names[0], "%s", e->d_name);
            l->types[l->n++] = video ? DT_CHR : DT_DIR;
        }
        l->dir = d;
        listings_open++;
    }
    pthread_mutex_unlock(&listing_lock);
    REAL(closedir)(reg);
out:
    errno = saved;
}

static struct listing *find_listing(DIR *d)
{
    for (int i = 0; i < MAX_LISTINGS; i++)
        if (listings[i].dir == d)
            return &listings[i];
    return NULL;
}

EXPORT DIR *opendir(const char *path)
{
    char r[PATH_MAX];
    DIR *d = REAL(opendir)(redirect(path, r) ? r : path);
    if (d && registry[0] && is_dev_dir(path))
        add_listing(d);
    return d;
}

/* The next registry entry of a /dev stream whose real entries are exhausted (NULL: none left). */
static const char *next_extra(DIR *d, unsigned char *type, long *ino)
{
    const char *name = NULL;
    struct listing *l;

    pthread_mutex_lock(&listing_lock);
    l = find_listing(d);
    if (l && l->next < l->n) {
        name = l->names[l->next];
        *type = l->types[l->next];
        *ino = 0x7e570000L + l->next;
        l->next++;
    }
    pthread_mutex_unlock(&listing_lock);
    return name;
}

EXPORT struct dirent *readdir(DIR *d)
{
    struct dirent *e = REAL(readdir)(d);
    unsigned char type;
    long ino;
    const char *name;

    if (e || !__atomic_load_n(&listings_open, __ATOMIC_ACQUIRE) || !(name = next_extra(d, &type, &ino)))
        return e;
    struct listing *l = find_listing(d);
    memset(&l->ent, 0, sizeof l->ent);
    l->ent.d_ino = (ino_t)ino;
    l->ent.d_type = type;
    l->ent.d_reclen = sizeof l->ent;
    snprintf(l->ent.d_name, sizeof l->ent.d_name, "%s", name);
    return &l->ent;
}

EXPORT struct dirent64 *readdir64(DIR *d)
{
    struct dirent64 *e = REAL(readdir64)(d);
    unsigned char type;
    long ino;
    const char *name;

    if (e || !__atomic_load_n(&listings_open, __ATOMIC_ACQUIRE) || !(name = next_extra(d, &type, &ino)))
        return e;
    struct listing *l = find_listing(d);
    memset(&l->ent64, 0, sizeof l->ent64);
    l->ent64.d_ino = (ino64_t)ino;
    l->ent64.d_type = type;
    l->ent64.d_reclen = sizeof l->ent64;
    snprintf(l->ent64.d_name, sizeof l->ent64.d_name, "%s", name);
    return &l->ent64;
}

EXPORT void rewinddir(DIR *d)
{
    if (__atomic_load_n(&listings_open, __ATOMIC_ACQUIRE)) {
        pthread_mutex_lock(&listing_lock);
        struct listing *l = find_listing(d);
        if (l)
            l->next = 0;
        pthread_mutex_unlock(&listing_lock);
    }
    REAL(rewinddir)(d);
}

EXPORT int closedir(DIR *d)
{
    if (__atomic_load_n(&listings_open, __ATOMIC_ACQUIRE)) {
        pthread_mutex_lock(&listing_lock);
        struct listing *l = find_listing(d);
        if (l) {
            l->dir = NULL;
            listings_open--;
        }
        pthread_mutex_unlock(&listing_lock);
    }
    return REAL(closedir)(d);
}

EXPORT int access(const char *path, int mode)
{
    char r[PATH_MAX];
    return REAL(access)(redirect(path, r) ? r : path, mode);
}

EXPORT int eaccess(const char *path, int mode)
{
    char r[PATH_MAX];
    return REAL(eaccess)(redirect(path, r) ? r : path, mode);
}

EXPORT int euidaccess(const char *path, int mode)
{
    char r[PATH_MAX];
    return REAL(euidaccess)(redirect(path, r) ? r : path, mode);
}

EXPORT int faccessat(int dirfd, const char *path, int mode, int flags)
{
    char r[PATH_MAX];
    return REAL(faccessat)(dirfd, path && path[0] == '/' && redirect(path, r) ? r : path, mode, flags);
}

EXPORT ssize_t readlink(const char *path, char *buf, size_t size)
{
    char r[PATH_MAX];
    return REAL(readlink)(redirect(path, r) ? r : path, buf, size);
}

EXPORT ssize_t readlinkat(int dirfd, const char *path, char *buf, size_t size)
{
    char r[PATH_MAX];
    return REAL(readlinkat)(dirfd, path && path[0] == '/' && redirect(path, r) ? r : path, buf, size);
}

/* Extended attributes (ls -l asks for ACLs): the registry's files answer for the paths they stand for. */
static ssize_t (*real_getxattr)(const char *, const char *, void *, size_t);
static ssize_t (*real_lgetxattr)(const char *, const char *, void *, size_t);
static ssize_t (*real_listxattr)(const char *, char *, size_t);
static ssize_t (*real_llistxattr)(const char *, char *, size_t);

EXPORT ssize_t getxattr(const char *path, const char *name, void *value, size_t size)
{
    char r[PATH_MAX];
    return REAL(getxattr)(redirect(path, r) ? r : path, name, value, size);
}

EXPORT ssize_t lgetxattr(const char *path, const char *name, void *value, size_t size)
{
    char r[PATH_MAX];
    return REAL(lgetxattr)(redirect(path, r) ? r : path, name, value, size);
}

EXPORT ssize_t listxattr(const char *path, char *list, size_t size)
{
    char r[PATH_MAX];
    return REAL(listxattr)(redirect(path, r) ? r : path, list, size);
}

EXPORT ssize_t llistxattr(const char *path, char *list, size_t size)
{
    char r[PATH_MAX];
    return REAL(llistxattr)(redirect(path, r) ? r : path, list, size);
}

/* -- stat: the node is a character device 81:N ------------------------------------------------------- */
static void as_char_device(struct stat *st, int minor)
{
    st->st_mode = S_IFCHR | (st->st_mode & 0777);
    st->st_rdev = makedev(VIDEO_MAJOR, minor);
    st->st_size = 0;
    st->st_blocks = 0;
    st->st_blksize = 4096;
}

/* 1: handled (result in *ret), 0: not emulated. */
static int emu_stat(const char *path, struct stat *st, int follow, int *ret)
{
    char r[PATH_MAX], sock[PATH_MAX];
    int minor;
    if (!redirect(path, r))
        return 0;
    *ret = raw_stat(r, st, follow);
    if (*ret == 0 && S_ISSOCK(st->st_mode) && device_node(path, sock, &minor))
        as_char_device(st, minor);
    return 1;
}

static int emu_fstat(int fd, struct stat *st, int *ret)
{
    struct conn *c = lookup(fd);
    if (!c)
        return 0;
    *ret = raw_stat(c->sockpath, st, 1);
    if (*ret == 0)
        as_char_device(st, c->minor);
    else {
        /* The node is gone (unplugged): the open file still exists. */
        memset(st, 0, sizeof *st);
        st->st_mode = S_IFCHR | 0660;
        st->st_rdev = makedev(VIDEO_MAJOR, c->minor);
        st->st_blksize = 4096;
        *ret = 0;
    }
    return 1;
}

EXPORT int stat(const char *path, struct stat *st)
{
    int ret;
    return emu_stat(path, st, 1, &ret) ? ret : REAL(stat)(path, st);
}

EXPORT int stat64(const char *path, struct stat64 *st)
{
    int ret;
    return emu_stat(path, (struct stat *)st, 1, &ret) ? ret : REAL(stat64)(path, st);
}

EXPORT int lstat(const char *path, struct stat *st)
{
    int ret;
    return emu_stat(path, st, 0, &ret) ? ret : REAL(lstat)(path, st);
}

EXPORT int lstat64(const char *path, struct stat64 *st)
{
    int ret;
    return emu_stat(path, (struct stat *)st, 0, &ret) ? ret : REAL(lstat64)(path, st);
}

EXPORT int fstat(int fd, struct stat *st)
{
    int ret;
    return emu_fstat(fd, st, &ret) ? ret : REAL(fstat)(fd, st);
}

EXPORT int fstat64(int fd, struct stat64 *st)
{
    int ret;
    return emu_fstat(fd, (struct stat *)st, &ret) ? ret : REAL(fstat64)(fd, st);
}

static int emu_fstatat(int dirfd, const char *path, struct stat *st, int flags, int *ret)
{
    if (path && path[0] == '\0' && (flags & AT_EMPTY_PATH))
        return emu_fstat(dirfd, st, ret);
    if (path && path[0] == '/')
        return emu_stat(path, st, !(flags & AT_SYMLINK_NOFOLLOW), ret);
    return 0;
}

EXPORT int fstatat(int dirfd, const char *path, struct stat *st, int flags)
{
    int ret;
    return emu_fstatat(dirfd, path, st, flags, &ret) ? ret : REAL(fstatat)(dirfd, path, st, flags);
}

EXPORT int fstatat64(int dirfd, const char *path, struct stat64 *st, int flags)
{
    int ret;
    return emu_fstatat(dirfd, path, (struct stat *)st, flags, &ret) ? ret : REAL(fstatat64)(dirfd, path, st, flags);
}

EXPORT int __xstat(int ver, const char *path, struct stat *st)
{
    int ret;
    return emu_stat(path, st, 1, &ret) ? ret : REAL(__xstat)(ver, path, st);
}

EXPORT int __xstat64(int ver, const char *path, struct stat64 *st)
{
    int ret;
    return emu_stat(path, (struct stat *)st, 1, &ret) ? ret : REAL(__xstat64)(ver, path, st);
}

EXPORT int __lxstat(int ver, const char *path, struct stat *st)
{
    int ret;
    return emu_stat(path, st, 0, &ret) ? ret : REAL(__lxstat)(ver, path, st);
}

EXPORT int __lxstat64(int ver, const char *path, struct stat64 *st)
{
    int ret;
    return emu_stat(path, (struct stat *)st, 0, &ret) ? ret : REAL(__lxstat64)(ver, path, st);
}

EXPORT int __fxstat(int ver, int fd, struct stat *st)
{
    int ret;
    return emu_fstat(fd, st, &ret) ? ret : REAL(__fxstat)(ver, fd, st);
}

EXPORT int __fxstat64(int ver, int fd, struct stat64 *st)
{
    int ret;
    return emu_fstat(fd, (struct stat *)st, &ret) ? ret : REAL(__fxstat64)(ver, fd, st);
}

EXPORT int __fxstatat(int ver, int dirfd, const char *path, struct stat *st, int flags)
{
    int ret;
    return emu_fstatat(dirfd, path, st, flags, &ret) ? ret : REAL(__fxstatat)(ver, dirfd, path, st, flags);
}

EXPORT int __fxstatat64(int ver, int dirfd, const char *path, struct stat64 *st, int flags)
{
    int ret;
    return emu_fstatat(dirfd, path, (struct stat *)st, flags, &ret) ? ret
                                                                    : REAL(__fxstatat64)(ver, dirfd, path, st, flags);
}

EXPORT int statx(int dirfd, const char *path, int flags, unsigned int mask, struct statx *sx)
{
    struct stat st;
    int ret;
    char r[PATH_MAX];

    if (emu_fstatat(dirfd, path, &st, flags, &ret)) {
        if (ret != 0)
            return ret;
        if (!sx) {
            errno = EFAULT;
            return -1;
        }
        /* A real statx first, for the fields struct stat lacks; then the device's own mode and numbers. */
        const char *target = NULL;
        struct conn *c = (path && path[0] == '\0') ? lookup(dirfd) : NULL;
        if (c)
            target = c->sockpath;
        else if (path && redirect(path, r))
            target = r;
        if (!target || REAL(statx)(AT_FDCWD, target, flags & ~AT_EMPTY_PATH, mask, sx) != 0)
            memset(sx, 0, sizeof *sx);
        sx->stx_mask |= STATX_TYPE | STATX_MODE | STATX_SIZE | STATX_BLOCKS;
        sx->stx_mode = (uint16_t)st.st_mode;
        sx->stx_size = (uint64_t)st.st_size;
        sx->stx_blocks = (uint64_t)st.st_blocks;
        sx->stx_blksize = (uint32_t)st.st_blksize;
        sx->stx_rdev_major = major(st.st_rdev);
        sx->stx_rdev_minor = minor(st.st_rdev);
        return 0;
    }
    return REAL(statx)(dirfd, path, flags, mask, sx);
}

/* -- ioctl ---------------------------------------------------------------------------------------- */
static int fd_nonblocking(int fd)
{
    int fl = REAL(fcntl)(fd, F_GETFL);
    return fl >= 0 && (fl & O_NONBLOCK);
}

static int wait_readable(int efd)
{
    struct pollfd p = { .fd = efd, .events = POLLIN };
    int n;
    do
        n = REAL(poll)(&p, 1, -1);
    while (n < 0 && errno == EINTR);
    return n;
}

static int is_ext_ctrls(unsigned long req)
{
    return req == VIDIOC_G_EXT_CTRLS || req == VIDIOC_S_EXT_CTRLS || req == VIDIOC_TRY_EXT_CTRLS;
}

static int emu_ioctl(struct conn *c, int fd, unsigned long req, void *arg)
{
    size_t size = _IOC_SIZE(req);
    int dir = _IOC_DIR(req);
    unsigned char *in = NULL, *out = NULL, *arr = NULL, *arr_out = NULL;
    size_t arr_len = 0;
    void *user_array = NULL;
    struct req q = { .op = OP_IOCTL, .cmd = req };
    struct rep r;
    int fds[3], res;

    if (size) {
        in = calloc(1, size);
        out = calloc(1, size);
        if (!in || !out) {
            free(in);
            free(out);
            errno = ENOMEM;
            return -1;
        }
    }
    if ((dir & _IOC_WRITE) && size) {
        if (copy_from_user(in, arg, size) < 0) {
            res = -EFAULT;
            goto done;
        }
        q.len = (uint32_t)size;
    }
    if (is_ext_ctrls(req) && size == sizeof(struct v4l2_ext_controls)) {
        struct v4l2_ext_controls *x = (struct v4l2_ext_controls *)in;
        if (x->count > 0 && x->count <= V4L2_CID_MAX_CTRLS) {
            arr_len = x->count * sizeof(struct v4l2_ext_control);
            user_array = x->controls;
            arr = malloc(arr_len);
            arr_out = malloc(arr_len);
            if (!arr || !arr_out) {
                res = -ENOMEM;
                goto done;
            }
            if (copy_from_user(arr, user_array, arr_len) < 0) {
                res = -EFAULT;
                goto done;
            }
            q.len2 = (uint32_t)arr_len;
        }
    }
    for (;;) {
        res = exchange(c, &q, in, arr, &r, out, size, arr_out, arr_len, fds, 3);
        /* A blocking DQBUF or DQEVENT waits here, outside the server: others may QBUF meanwhile. */
        if (res == -EAGAIN && req == VIDIOC_DQBUF && !fd_nonblocking(fd) && wait_readable(c->efd_wait) > 0)
            continue;
        if (res == -ENOENT && req == VIDIOC_DQEVENT && !fd_nonblocking(fd) && wait_readable(c->efd_pri) > 0)
            continue;
        break;
    }
    if (req == VIDIOC_EXPBUF && res >= 0 && fds[0] >= 0) {
        struct v4l2_exportbuffer *e = (struct v4l2_exportbuffer *)out;
        int flags = e->flags;
        if (!(flags & O_CLOEXEC))
            REAL(fcntl)(fds[0], F_SETFD, 0);
        e->fd = fds[0];
        fds[0] = -1;
    }
    for (int i = 0; i < 3; i++)
        if (fds[i] >= 0)
            REAL(close)(fds[i]);
    /* video_usercopy: the control array goes back always, the structure on success (always for
     * the EXT_CTRLS ioctls, whose error_idx is a result). */
    if (arr_len && r.len2 == arr_len && copy_to_user(user_array, arr_out, arr_len) < 0)
        res = -EFAULT;
    if ((dir & _IOC_READ) && size && (res >= 0 || is_ext_ctrls(req))) {
        if (user_array)
            ((struct v4l2_ext_controls *)out)->controls = user_array;
        if (copy_to_user(arg, out, size) < 0)
            res = -EFAULT;
    }
done:
    free(in);
    free(out);
    free(arr);
    free(arr_out);
    if (res < 0) {
        errno = -res;
        return -1;
    }
    return res;
}

EXPORT int ioctl(int fd, unsigned long req, ...)
{
    va_list ap;
    void *arg;
    struct conn *c;

    va_start(ap, req);
    arg = va_arg(ap, void *);
    va_end(ap);
    c = lookup(fd);
    if (!c)
        return REAL(ioctl)(fd, req, arg);
    return emu_ioctl(c, fd, req, arg);
}

/* -- mmap -------------------------------------------------------------------------------------------- */
static void *emu_mmap(struct conn *c, void *addr, size_t len, int prot, int flags, off_t off)
{
    struct req q = { .op = OP_MMAP, .arg0 = prot, .cmd = (uint64_t)flags, .arg1 = (uint64_t)off, .arg2 = len };
    struct rep r;
    int fds[3];
    int res = exchange(c, &q, NULL, NULL, &r, NULL, 0, NULL, 0, fds, 3);
    void *p;

    if (res < 0 || fds[0] < 0) {
        for (int i = 0; i < 3; i++)
            if (fds[i] >= 0)
                REAL(close)(fds[i]);
        errno = res < 0 ? -res : ENODEV;
        return MAP_FAILED;
    }
    p = REAL(mmap)(addr, len, prot, flags, fds[0], 0);
    for (int i = 0; i < 3; i++)
        if (fds[i] >= 0)
            REAL(close)(fds[i]);
    if (p == MAP_FAILED)
        return p;
    pthread_mutex_lock(&table_lock);
    if (n_maps < MAX_MAPS) {
        maps[n_maps++] = (struct mapping){ p, len, (uint64_t)off, c };
        c->maps++;
    }
    pthread_mutex_unlock(&table_lock);
    return p;
}

EXPORT void *mmap(void *addr, size_t len, int prot, int flags, int fd, off_t off)
{
    struct conn *c = lookup(fd);
    return c ? emu_mmap(c, addr, len, prot, flags, off) : REAL(mmap)(addr, len, prot, flags, fd, off);
}

EXPORT void *mmap64(void *addr, size_t len, int prot, int flags, int fd, off64_t off)
{
    struct conn *c = lookup(fd);
    return c ? emu_mmap(c, addr, len, prot, flags, (off_t)off) : REAL(mmap64)(addr, len, prot, flags, fd, off);
}

EXPORT int munmap(void *addr, size_t len)
{
    int ret = REAL(munmap)(addr, len);
    struct conn *c = NULL;
    uint64_t offset = 0;

    if (ret != 0 || !__atomic_load_n(&n_maps, __ATOMIC_RELAXED))
        return ret;
    pthread_mutex_lock(&table_lock);
    for (int i = 0; i < n_maps; i++) {
        if (maps[i].addr == addr) {
            c = maps[i].c;
            offset = maps[i].offset;
            maps[i] = maps[--n_maps];
            c->maps--;
            break;
        }
    }
    /* The server learns the mapping is gone (vb2's V4L2_BUF_FLAG_MAPPED), if the file is still open. */
    int notify = c && !c->closed;
    if (c && notify)
        c->refs++; /* keep it alive across the message */
    if (c && !notify)
        conn_free_if_unused(c);
    pthread_mutex_unlock(&table_lock);
    if (notify) {
        int saved = errno;
        simple(c, OP_MUNMAP, 0, 0, offset, len);
        errno = saved;
        pthread_mutex_lock(&table_lock);
        c->refs--;
        conn_free_if_unused(c);
        pthread_mutex_unlock(&table_lock);
    }
    return ret;
}

/* -- read, write, close, dup --------------------------------------------------------------------------- */
EXPORT ssize_t read(int fd, void *buf, size_t n)
{
    struct conn *c = lookup(fd);
    if (!c)
        return REAL(read)(fd, buf, n);
    int res = simple(c, OP_READ, 0, 0, (uint64_t)n, 0); /* uvcvideo has no read(): EINVAL */
    errno = res < 0 ? -res : EINVAL;
    return -1;
}

EXPORT ssize_t __read_chk(int fd, void *buf, size_t n, size_t buflen)
{
    if (!lookup(fd))
        return REAL(__read_chk)(fd, buf, n, buflen);
    return read(fd, buf, n);
}

EXPORT ssize_t write(int fd, const void *buf, size_t n)
{
    if (!lookup(fd))
        return REAL(write)(fd, buf, n);
    errno = EINVAL; /* a capture node has no write(): v4l2_write returns EINVAL */
    return -1;
}

EXPORT int close(int fd)
{
    if (lookup(fd)) {
        pthread_mutex_lock(&table_lock);
        table_set(fd, NULL);
        pthread_mutex_unlock(&table_lock);
    }
    return REAL(close)(fd);
}

/* Closing a range of descriptors closes the emulated ones among them too. */
static void forget_range(unsigned int first, unsigned int last)
{
    if (!__atomic_load_n(&n_emulated, __ATOMIC_RELAXED))
        return;
    pthread_mutex_lock(&table_lock);
    for (unsigned int fd = first; fd <= last && fd < MAX_FDS; fd++)
        if (table && table[fd])
            table_set((int)fd, NULL);
    pthread_mutex_unlock(&table_lock);
}

static int (*real_close_range)(unsigned int, unsigned int, int);
static void (*real_closefrom)(int);

EXPORT int close_range(unsigned int first, unsigned int last, int flags)
{
    if (!(flags & CLOSE_RANGE_CLOEXEC))
        forget_range(first, last);
    return REAL(close_range)(first, last, flags);
}

EXPORT void closefrom(int lowfd)
{
    forget_range(lowfd < 0 ? 0 : (unsigned int)lowfd, UINT_MAX);
    REAL(closefrom)(lowfd);
}

static int after_dup(int oldfd, int newfd, struct conn *c)
{
    if (newfd >= 0 && c) {
        pthread_mutex_lock(&table_lock);
        if (newfd < MAX_FDS && table)
            table_set(newfd, c);
        pthread_mutex_unlock(&table_lock);
    }
    (void)oldfd;
    return newfd;
}

EXPORT int dup(int fd)
{
    struct conn *c = lookup(fd);
    return after_dup(fd, REAL(dup)(fd), c);
}

static int emu_dup23(int oldfd, int newfd, int flags, int three)
{
    struct conn *c = lookup(oldfd);
    if (oldfd != newfd && lookup(newfd)) { /* newfd is silently closed first */
        pthread_mutex_lock(&table_lock);
        table_set(newfd, NULL);
        pthread_mutex_unlock(&table_lock);
    }
    int r = three ? REAL(dup3)(oldfd, newfd, flags) : REAL(dup2)(oldfd, newfd);
    if (r < 0 || oldfd == newfd)
        return r;
    return after_dup(oldfd, r, c);
}

EXPORT int dup2(int oldfd, int newfd) { return emu_dup23(oldfd, newfd, 0, 0); }
EXPORT int dup3(int oldfd, int newfd, int flags) { return emu_dup23(oldfd, newfd, flags, 1); }

static int emu_fcntl(int fd, int cmd, void *arg, int wide)
{
    struct conn *c = (cmd == F_DUPFD || cmd == F_DUPFD_CLOEXEC) ? lookup(fd) : NULL;
    int r = wide ? REAL(fcntl64)(fd, cmd, arg) : REAL(fcntl)(fd, cmd, arg);
    return c ? after_dup(fd, r, c) : r;
}

EXPORT int fcntl(int fd, int cmd, ...)
{
    va_list ap;
    va_start(ap, cmd);
    void *arg = va_arg(ap, void *);
    va_end(ap);
    return emu_fcntl(fd, cmd, arg, 0);
}

EXPORT int fcntl64(int fd, int cmd, ...)
{
    va_list ap;
    va_start(ap, cmd);
    void *arg = va_arg(ap, void *);
    va_end(ap);
    return emu_fcntl(fd, cmd, arg, 1);
}

/* -- poll and select -------------------------------------------------------------------------------- */
static int64_t now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000 + t.tv_nsec / 1000000;
}

static int any_emulated(const struct pollfd *fds, nfds_t n)
{
    if (!__atomic_load_n(&n_emulated, __ATOMIC_RELAXED))
        return 0;
    for (nfds_t i = 0; i < n; i++)
        if (lookup(fds[i].fd))
            return 1;
    return 0;
}

/*
 * poll() with emulated descriptors: the real poll waits on the server's eventfds (the descriptor
 * itself is readable while a POLLIN-class answer is due, efd_pri while an event is pending), and
 * the server says which bits to report. `timeout_ms` < 0 waits forever; ppoll passes its sigmask.
 */
static int emu_poll(struct pollfd *fds, nfds_t n, int timeout_ms, const sigset_t *sigmask)
{
    struct pollfd *w = calloc(2 * n + 1, sizeof *w);
    struct conn **cs = calloc(n + 1, sizeof *cs);
    int64_t deadline = timeout_ms < 0 ? -1 : now_ms() + timeout_ms;
    int ready = -1;

    if (!w || !cs) {
        free(w);
        free(cs);
        errno = ENOMEM;
        return -1;
    }
    for (;;) {
        for (nfds_t i = 0; i < n; i++) {
            cs[i] = lookup(fds[i].fd);
            w[i] = fds[i];
            w[n + i] = (struct pollfd){ .fd = -1 };
            if (cs[i]) {
                w[i].fd = (fds[i].events & (POLLIN | POLLRDNORM)) ? fds[i].fd : -1;
                w[i].events = POLLIN;
                if (fds[i].events & POLLPRI)
                    w[n + i] = (struct pollfd){ .fd = cs[i]->efd_pri, .events = POLLIN };
            }
            w[i].revents = 0;
        }
        int left = -1;
        if (deadline >= 0) {
            int64_t d = deadline - now_ms();
            left = d < 0 ? 0 : (int)(d > INT_MAX ? INT_MAX : d);
        }
        int k;
        if (sigmask) {
            struct timespec ts = { left / 1000, (left % 1000) * 1000000L };
            k = REAL(ppoll)(w, 2 * n, left < 0 ? NULL : &ts, sigmask);
        } else
            k = REAL(poll)(w, 2 * n, left);
        if (k < 0)
            break;
        ready = 0;
        for (nfds_t i = 0; i < n; i++) {
            fds[i].revents = 0;
            if (!cs[i]) {
                fds[i].revents = w[i].revents;
            } else if (w[i].revents || w[n + i].revents) {
                int rev = simple(cs[i], OP_POLL, fds[i].events, 0, 0, 0);
                if (rev < 0)
                    rev = POLLERR | POLLHUP | POLLPRI;
                fds[i].revents = (short)(rev & (fds[i].events | POLLERR | POLLHUP | POLLNVAL));
            }
            if (fds[i].revents)
                ready++;
        }
        if (ready || (deadline >= 0 && now_ms() >= deadline))
            break;
        /* A wake whose cause another reader consumed first: wait again for what is left. */
    }
    free(w);
    free(cs);
    return ready;
}

EXPORT int poll(struct pollfd *fds, nfds_t n, int timeout)
{
    if (!any_emulated(fds, n))
        return REAL(poll)(fds, n, timeout);
    return emu_poll(fds, n, timeout, NULL);
}

EXPORT int __poll_chk(struct pollfd *fds, nfds_t n, int timeout, size_t fdslen)
{
    if (!any_emulated(fds, n))
        return REAL(__poll_chk)(fds, n, timeout, fdslen);
    return emu_poll(fds, n, timeout, NULL);
}

static int ts_to_ms(const struct timespec *ts)
{
    if (!ts)
        return -1;
    int64_t ms = (int64_t)ts->tv_sec * 1000 + (ts->tv_nsec + 999999) / 1000000;
    return ms > INT_MAX ? INT_MAX : (int)ms;
}

EXPORT int ppoll(struct pollfd *fds, nfds_t n, const struct timespec *ts, const sigset_t *sigmask)
{
    if (!any_emulated(fds, n))
        return REAL(ppoll)(fds, n, ts, sigmask);
    return emu_poll(fds, n, ts_to_ms(ts), sigmask);
}

EXPORT int __ppoll_chk(struct pollfd *fds, nfds_t n, const struct timespec *ts, const sigset_t *sigmask, size_t len)
{
    if (!any_emulated(fds, n))
        return REAL(__ppoll_chk)(fds, n, ts, sigmask, len);
    return emu_poll(fds, n, ts_to_ms(ts), sigmask);
}

/* select() in terms of poll(), with the kernel's event sets (fs/select.c): readable on
 * POLLIN|POLLRDNORM|POLLRDBAND|POLLHUP|POLLERR, writable on POLLOUT|POLLWRNORM|POLLWRBAND|POLLERR,
 * exceptional on POLLPRI; POLLPRI is always asked for. */
static int emu_select(int nfds, fd_set *rd, fd_set *wr, fd_set *ex, int timeout_ms, const sigset_t *sigmask)
{
    struct pollfd *p = calloc((size_t)(nfds > 0 ? nfds : 1), sizeof *p);
    int n = 0, count = 0;
    if (!p) {
        errno = ENOMEM;
        return -1;
    }
    for (int fd = 0; fd < nfds; fd++) {
        short ev = 0;
        if (rd && FD_ISSET(fd, rd))
            ev |= POLLIN | POLLRDNORM;
        if (wr && FD_ISSET(fd, wr))
            ev |= POLLOUT | POLLWRNORM;
        if (ex && FD_ISSET(fd, ex))
            ev |= POLLPRI;
        if (ev)
            p[n++] = (struct pollfd){ .fd = fd, .events = (short)(ev | POLLPRI) };
    }
    int k = emu_poll(p, (nfds_t)n, timeout_ms, sigmask);
    if (k < 0) {
        free(p);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        if (p[i].revents & POLLNVAL) {
            free(p);
            errno = EBADF;
            return -1;
        }
    }
    for (int i = 0; i < n; i++) {
        int fd = p[i].fd;
        short rv = p[i].revents;
        int in = rd && FD_ISSET(fd, rd), out = wr && FD_ISSET(fd, wr), exc = ex && FD_ISSET(fd, ex);
        if (rd)
            FD_CLR(fd, rd);
        if (wr)
            FD_CLR(fd, wr);
        if (ex)
            FD_CLR(fd, ex);
        if (in && (rv & (POLLIN | POLLRDNORM | POLLRDBAND | POLLHUP | POLLERR))) {
            FD_SET(fd, rd);
            count++;
        }
        if (out && (rv & (POLLOUT | POLLWRNORM | POLLWRBAND | POLLERR))) {
            FD_SET(fd, wr);
            count++;
        }
        if (exc && (rv & POLLPRI)) {
            FD_SET(fd, ex);
            count++;
        }
    }
    free(p);
    return count;
}

static int sets_have_emulated(int nfds, fd_set *rd, fd_set *wr, fd_set *ex)
{
    if (!__atomic_load_n(&n_emulated, __ATOMIC_RELAXED))
        return 0;
    for (int fd = 0; fd < nfds && fd < FD_SETSIZE; fd++)
        if (((rd && FD_ISSET(fd, rd)) || (wr && FD_ISSET(fd, wr)) || (ex && FD_ISSET(fd, ex))) && lookup(fd))
            return 1;
    return 0;
}

EXPORT int select(int nfds, fd_set *rd, fd_set *wr, fd_set *ex, struct timeval *tv)
{
    if (!sets_have_emulated(nfds, rd, wr, ex))
        return REAL(select)(nfds, rd, wr, ex, tv);
    int ms = tv ? (int)(tv->tv_sec * 1000 + (tv->tv_usec + 999) / 1000) : -1;
    int64_t start = now_ms();
    int r = emu_select(nfds, rd, wr, ex, ms, NULL);
    if (tv) { /* Linux select() leaves the time not slept */
        int64_t left = ms - (now_ms() - start);
        if (left < 0)
            left = 0;
        tv->tv_sec = left / 1000;
        tv->tv_usec = (left % 1000) * 1000;
    }
    return r;
}

EXPORT int pselect(int nfds, fd_set *rd, fd_set *wr, fd_set *ex, const struct timespec *ts, const sigset_t *sigmask)
{
    if (!sets_have_emulated(nfds, rd, wr, ex))
        return REAL(pselect)(nfds, rd, wr, ex, ts, sigmask);
    return emu_select(nfds, rd, wr, ex, ts_to_ms(ts), sigmask);
}

/* -- raw syscall(): libv4l2 reaches the device through it ------------------------------------------------ */
EXPORT long syscall(long number, ...)
{
    va_list ap;
    long a[6];
    va_start(ap, number);
    for (int i = 0; i < 6; i++)
        a[i] = va_arg(ap, long);
    va_end(ap);

    if (registry[0]) {
        switch (number) {
        case SYS_ioctl:
            if (lookup((int)a[0]))
                return ioctl((int)a[0], (unsigned long)a[1], (void *)a[2]);
            break;
#ifdef SYS_open
        case SYS_open:
            return open((const char *)a[0], (int)a[1], (mode_t)a[2]);
#endif
        case SYS_openat:
            return openat((int)a[0], (const char *)a[1], (int)a[2], (mode_t)a[3]);
        case SYS_close:
            if (lookup((int)a[0]))
                return close((int)a[0]);
            break;
        case SYS_read:
            if (lookup((int)a[0]))
                return read((int)a[0], (void *)a[1], (size_t)a[2]);
            break;
        case SYS_write:
            if (lookup((int)a[0]))
                return write((int)a[0], (const void *)a[1], (size_t)a[2]);
            break;
        case SYS_mmap:
            if (lookup((int)a[4]))
                return (long)mmap((void *)a[0], (size_t)a[1], (int)a[2], (int)a[3], (int)a[4], (off_t)a[5]);
            break;
        case SYS_munmap:
            return munmap((void *)a[0], (size_t)a[1]);
        default:
            break;
        }
    }
    return REAL(syscall)(number, a[0], a[1], a[2], a[3], a[4], a[5]);
}

/* -- fork: a child reconnects on first use (see reattach); its copies of the locks start free ----------- */
static void atfork_child(void)
{
    pthread_mutex_init(&table_lock, NULL);
    pthread_mutex_init(&probe_lock, NULL);
    struct conn **t = table;
    if (!t)
        return;
    for (int fd = 0; fd < MAX_FDS; fd++)
        if (t[fd])
            pthread_mutex_init(&t[fd]->lock, NULL);
}

__attribute__((constructor)) static void init_fork(void)
{
    pthread_atfork(NULL, NULL, atfork_child);
}
