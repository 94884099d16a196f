// uml-noxstate: runs a command whose ptrace(PTRACE_GETREGSET / PTRACE_SETREGSET, pid,
// NT_X86_XSTATE, ...) requests fail with EIO (a seccomp filter, inherited by its children).
//
// Debian 12's user-mode-linux 6.1 saves its guests' FP state through those requests with a buffer
// too small for the XSAVE area of a host with AMX tiles: "ptrace set fp regs failed, errno = 14"
// and a kernel panic at boot. Refused the requests, UML falls back to the i387/SSE state
// (PTRACE_GETFPREGS); tests/vcan/vcan-run then tells the guest's glibc not to use AVX, whose
// upper register halves that state does not carry. Used by vcan-run on such hosts only.
#include <errno.h>
#include <linux/filter.h>
#include <linux/seccomp.h>
#include <stddef.h>
#include <stdio.h>
#include <sys/prctl.h>
#include <sys/syscall.h>
#include <unistd.h>

int main(int argc, char** argv) {
  if (argc < 2) {
    fprintf(stderr, "usage: uml-noxstate CMD ARGS...\n");
    return 2;
  }
  enum { kGetRegset = 0x4204, kSetRegset = 0x4205, kXstate = 0x202 };
  struct sock_filter f[] = {
      BPF_STMT(BPF_LD | BPF_W | BPF_ABS, offsetof(struct seccomp_data, nr)),
      BPF_JUMP(BPF_JMP | BPF_JEQ | BPF_K, __NR_ptrace, 0, 5),
      BPF_STMT(BPF_LD | BPF_W | BPF_ABS, offsetof(struct seccomp_data, args[0])),
      BPF_JUMP(BPF_JMP | BPF_JEQ | BPF_K, kGetRegset, 1, 0),
      BPF_JUMP(BPF_JMP | BPF_JEQ | BPF_K, kSetRegset, 0, 2),
      BPF_STMT(BPF_LD | BPF_W | BPF_ABS, offsetof(struct seccomp_data, args[2])),
      BPF_JUMP(BPF_JMP | BPF_JEQ | BPF_K, kXstate, 1, 0),
      BPF_STMT(BPF_RET | BPF_K, SECCOMP_RET_ALLOW),
      BPF_STMT(BPF_RET | BPF_K, SECCOMP_RET_ERRNO | (EIO & SECCOMP_RET_DATA)),
  };
  struct sock_fprog prog = {(unsigned short)(sizeof(f) / sizeof(f[0])), f};
  if (prctl(PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0 ||
      prctl(PR_SET_SECCOMP, SECCOMP_MODE_FILTER, &prog) != 0) {
    perror("uml-noxstate: seccomp");
    return 126;
  }
  execvp(argv[1], argv + 1);
  perror("uml-noxstate: exec");
  return 127;
}
