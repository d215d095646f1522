#include "common/isolate.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <exception>

#include "common/error.hpp"

namespace trocar {
namespace {

constexpr char kOk = 'O';          // the work's output follows
constexpr char kError = 'E';       // a trocar::Error's message follows
constexpr char kException = 'X';   // another exception's message follows
constexpr off_t kStderrBytes = 64 * 1024;
constexpr std::uint64_t kTooLong = ~std::uint64_t{0};  // the answer's length when over the limit

// An anonymous in-memory file that cannot grow past `max_bytes` once sealed.
int MakeBoundedFile(const char* name, off_t max_bytes) {
  const int fd = static_cast<int>(::syscall(SYS_memfd_create, name, MFD_CLOEXEC | MFD_ALLOW_SEALING));
  if (fd < 0) return -1;
  if (::ftruncate(fd, max_bytes) != 0 || ::fcntl(fd, F_ADD_SEALS, F_SEAL_GROW | F_SEAL_SHRINK) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// Writes all of `data` to `fd` at `offset`; false when it does not fit.
bool WriteAllAt(int fd, const char* data, std::size_t size, off_t offset) {
  while (size > 0) {
    const ssize_t n = ::pwrite(fd, data, size, offset);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
    offset += n;
  }
  return true;
}

bool ReadAllAt(int fd, char* data, std::size_t size, off_t offset) {
  while (size > 0) {
    const ssize_t n = ::pread(fd, data, size, offset);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
    offset += n;
  }
  return true;
}

// The child: runs the work and leaves its answer in `out_fd` as [length: 8 bytes][status][bytes].
[[noreturn]] void RunChild(int out_fd, int err_fd, std::uint64_t max_bytes,
                           const std::function<void(std::string*)>& work) {
  // A crash here ends this child only: no handler inherited from the parent (a fuzzer's or a
  // sanitizer's crash report, which would write artifacts and exit as if the parent had crashed).
  for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGTRAP, SIGALRM, SIGTERM, SIGINT}) {
    ::signal(sig, SIG_DFL);
  }
  if (err_fd >= 0) ::dup2(err_fd, STDERR_FILENO);
  std::string message;
  try {
    std::string body;
    work(&body);
    message.reserve(body.size() + 1);
    message.assign(1, kOk).append(body);
  } catch (const Error& e) {
    message.assign(1, kError).append(e.what());
  } catch (const std::exception& e) {
    message.assign(1, kException).append(e.what());
  } catch (...) {
    message.assign(1, kException).append("an exception that is not a std::exception");
  }
  // An answer over the limit is not sent: its length alone says so (kTooLong).
  std::uint64_t length = message.size() <= max_bytes ? message.size() : kTooLong;
  if (length != kTooLong &&
      !WriteAllAt(out_fd, message.data(), message.size(), sizeof length)) {
    length = kTooLong;
  }
  WriteAllAt(out_fd, reinterpret_cast<const char*>(&length), sizeof length, 0);
  // _exit: no atexit handlers, no static destructors, no flush of the parent's stdio buffers.
  ::_exit(0);
}

// Waits for the child up to `timeout_ms`; false when it is still running then. With a pidfd
// (Linux 5.3 on) this is one poll, whatever the timing; older kernels look every millisecond.
bool WaitFor(pid_t pid, int* status, long long timeout_ms) {
  const int pidfd = static_cast<int>(::syscall(SYS_pidfd_open, pid, 0));
  if (pidfd >= 0) {
    pollfd p{pidfd, POLLIN, 0};
    int ready;
    do {
      ready = ::poll(&p, 1, static_cast<int>(std::min<long long>(timeout_ms, 1LL << 30)));
    } while (ready < 0 && errno == EINTR);
    ::close(pidfd);
    if (ready == 0) return false;
    while (::waitpid(pid, status, 0) < 0 && errno == EINTR) {
    }
    return true;
  }
  for (long long waited = 0;; ++waited) {
    const pid_t done = ::waitpid(pid, status, WNOHANG);
    if (done == pid || (done < 0 && errno != EINTR)) return true;
    if (waited >= timeout_ms) return false;
    ::usleep(1000);
  }
}

// The last few lines a child printed, for the message.
std::string Tail(int err_fd) {
  char buffer[kStderrBytes];
  const ssize_t n = err_fd < 0 ? 0 : ::pread(err_fd, buffer, sizeof buffer, 0);
  std::string err(buffer, n > 0 ? static_cast<std::size_t>(n) : 0);
  err.erase(std::find(err.begin(), err.end(), '\0'), err.end());  // the unwritten rest is zeros
  std::string t = err.size() > 400 ? "..." + err.substr(err.size() - 400) : err;
  while (!t.empty() && (t.back() == '\n' || t.back() == ' ')) t.pop_back();
  for (char& c : t) {
    if (c == '\n') c = ' ';
  }
  return t.empty() ? std::string() : " (it printed: \"" + t + "\")";
}

}  // namespace

// The child answers through an in-memory file, read once it has ended (not through a pipe read
// as it comes): the parent then does the same steps whatever the timing, so a fuzzer that
// follows coverage sees the same run twice.
std::string RunIsolated(const std::string& what, const std::function<void(std::string* out)>& work,
                        const IsolateOptions& options) {
  const std::uint64_t max_bytes = options.max_output_bytes + 1;  // the status byte
  const int out_fd = MakeBoundedFile("trocar-isolated-answer",
                                     static_cast<off_t>(max_bytes + sizeof(std::uint64_t)));
  TROCAR_THROW_UNLESS(out_fd >= 0, what << ": cannot start the decoder process (memfd: "
                                        << std::strerror(errno) << ")");
  const int err_fd = MakeBoundedFile("trocar-isolated-stderr", kStderrBytes);  // optional
  const pid_t pid = ::fork();
  if (pid == 0) RunChild(out_fd, err_fd, max_bytes, work);
  if (pid < 0) {
    const int e = errno;
    ::close(out_fd);
    if (err_fd >= 0) ::close(err_fd);
    TROCAR_THROW(what << ": cannot start the decoder process (fork: " << std::strerror(e) << ")");
  }
  int status = 0;
  const bool finished =
      WaitFor(pid, &status, static_cast<long long>(std::ceil(options.timeout_s * 1000.0)));
  if (!finished) {
    ::kill(pid, SIGKILL);
    while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
    }
  }
  std::uint64_t length = 0;
  std::string out;
  const bool has_length = ReadAllAt(out_fd, reinterpret_cast<char*>(&length), sizeof length, 0);
  const bool exited = finished && WIFEXITED(status);
  if (exited && WEXITSTATUS(status) == 0 && has_length && length >= 1 && length <= max_bytes) {
    out.resize(length);
    if (!ReadAllAt(out_fd, out.data(), length, sizeof length)) out.clear();
  }
  const std::string tail = Tail(err_fd);
  ::close(out_fd);
  if (err_fd >= 0) ::close(err_fd);
  TROCAR_THROW_UNLESS(finished, what << ": the decoder did not finish within " << options.timeout_s
                                     << " s and was stopped (a damaged or hostile file?)");
  TROCAR_THROW_UNLESS(!WIFSIGNALED(status),
                      what << ": the decoder crashed on it (signal " << WTERMSIG(status) << ", "
                           << ::strsignal(WTERMSIG(status)) << ")" << tail
                           << "; the file is damaged or uses an encoding the library cannot read");
  TROCAR_THROW_UNLESS(!(exited && WEXITSTATUS(status) == 0 && has_length && length == kTooLong),
                      what << ": the decoder produced more than " << options.max_output_bytes
                           << " bytes and was stopped");
  TROCAR_THROW_UNLESS(exited && WEXITSTATUS(status) == 0 && !out.empty(),
                      what << ": the decoder ended without an answer (exit status "
                           << (exited ? WEXITSTATUS(status) : -1) << ")" << tail);
  const char kind = out.front();
  out.erase(0, 1);
  if (kind == kError) internal::ThrowError(out);
  TROCAR_THROW_UNLESS(kind == kOk, what << ": the decoder failed: " << out);
  return out;
}

}  // namespace trocar
