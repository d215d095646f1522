#include "common/isolate.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstring>
#include <exception>

#include "common/error.hpp"

namespace trocar {
namespace {

constexpr char kOk = 'O';          // the work's output follows
constexpr char kError = 'E';       // a trocar::Error's message follows
constexpr char kException = 'X';   // another exception's message follows
constexpr std::size_t kStderrTail = 2048;

// Writes all of `data` to `fd`; false when the reader has gone.
bool WriteAll(int fd, const char* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::write(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

[[noreturn]] void RunChild(int out_fd, int err_fd, const std::function<void(std::string*)>& work) {
  ::signal(SIGPIPE, SIG_IGN);
  ::dup2(err_fd, STDERR_FILENO);
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
  WriteAll(out_fd, message.data(), message.size());
  // _exit: no atexit handlers, no static destructors, no flush of the parent's stdio buffers.
  ::_exit(0);
}

// The last few lines a child printed, for the message.
std::string Tail(const std::string& err) {
  std::string t = err.size() > 400 ? "..." + err.substr(err.size() - 400) : err;
  while (!t.empty() && (t.back() == '\n' || t.back() == ' ')) t.pop_back();
  for (char& c : t) {
    if (c == '\n') c = ' ';
  }
  return t.empty() ? std::string() : " (it printed: \"" + t + "\")";
}

}  // namespace

std::string RunIsolated(const std::string& what, const std::function<void(std::string* out)>& work,
                        const IsolateOptions& options) {
  int out_pipe[2], err_pipe[2];
  TROCAR_THROW_UNLESS(::pipe2(out_pipe, O_CLOEXEC) == 0,
                      what << ": cannot start the decoder process (pipe: " << std::strerror(errno) << ")");
  if (::pipe2(err_pipe, O_CLOEXEC) != 0) {
    const int e = errno;
    ::close(out_pipe[0]);
    ::close(out_pipe[1]);
    TROCAR_THROW(what << ": cannot start the decoder process (pipe: " << std::strerror(e) << ")");
  }
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(out_pipe[0]);
    ::close(err_pipe[0]);
    RunChild(out_pipe[1], err_pipe[1], work);
  }
  ::close(out_pipe[1]);
  ::close(err_pipe[1]);
  if (pid < 0) {
    const int e = errno;
    ::close(out_pipe[0]);
    ::close(err_pipe[0]);
    TROCAR_THROW(what << ": cannot start the decoder process (fork: " << std::strerror(e) << ")");
  }

  std::string out, err;
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::duration<double>(options.timeout_s);
  const std::uint64_t max_bytes = options.max_output_bytes + 1;  // the status byte
  bool over = false, timed_out = false;
  pollfd fds[2] = {{out_pipe[0], POLLIN, 0}, {err_pipe[0], POLLIN, 0}};
  int open_fds = 2;
  char buffer[65536];
  while (open_fds > 0) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      timed_out = true;
      break;
    }
    const int ready = ::poll(fds, 2, static_cast<int>(std::min<long long>(left.count(), 1000)));
    if (ready < 0 && errno == EINTR) continue;
    if (ready < 0) break;
    for (int k = 0; k < 2; ++k) {
      if (fds[k].fd < 0 || fds[k].revents == 0) continue;
      const ssize_t n = ::read(fds[k].fd, buffer, sizeof buffer);
      if (n < 0 && (errno == EINTR || errno == EAGAIN)) continue;
      if (n <= 0) {
        ::close(fds[k].fd);
        fds[k].fd = -1;
        --open_fds;
        continue;
      }
      if (k == 0) {
        if (out.size() + static_cast<std::size_t>(n) > max_bytes) {
          over = true;
          break;
        }
        out.append(buffer, static_cast<std::size_t>(n));
      } else {
        err.append(buffer, static_cast<std::size_t>(n));
        if (err.size() > 2 * kStderrTail) err.erase(0, err.size() - kStderrTail);
      }
    }
    if (over) break;
  }
  for (const pollfd& p : fds) {
    if (p.fd >= 0) ::close(p.fd);
  }
  if (over || timed_out) ::kill(pid, SIGKILL);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  TROCAR_THROW_UNLESS(!timed_out, what << ": the decoder did not finish within " << options.timeout_s
                                       << " s and was stopped (a damaged or hostile file?)");
  TROCAR_THROW_UNLESS(!over, what << ": the decoder produced more than " << options.max_output_bytes
                                  << " bytes and was stopped");
  TROCAR_THROW_UNLESS(!WIFSIGNALED(status),
                      what << ": the decoder crashed on it (signal " << WTERMSIG(status) << ", "
                           << ::strsignal(WTERMSIG(status)) << ")" << Tail(err)
                           << "; the file is damaged or uses an encoding the library cannot read");
  TROCAR_THROW_UNLESS(WIFEXITED(status) && WEXITSTATUS(status) == 0 && !out.empty(),
                      what << ": the decoder ended without an answer (exit status "
                           << (WIFEXITED(status) ? WEXITSTATUS(status) : -1) << ")" << Tail(err));
  const char kind = out.front();
  out.erase(0, 1);
  if (kind == kError) internal::ThrowError(out);
  TROCAR_THROW_UNLESS(kind == kOk, what << ": the decoder failed: " << out);
  return out;
}

}  // namespace trocar
