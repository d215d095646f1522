#include "common/isolate.hpp"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <exception>

#include "common/error.hpp"

namespace trocar {
namespace {

constexpr char kOk = 'O';          // the work's answer follows
constexpr char kError = 'E';       // a trocar::Error's message follows
constexpr char kException = 'X';   // another exception's message follows
constexpr std::size_t kStderrTail = 2048;
constexpr std::uint64_t kTooLong = ~std::uint64_t{0};  // the answer's length when over the limit

// Sends all of `data` on the socket `fd` (no SIGPIPE); false when the other side has gone.
bool SendAll(int fd, const char* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::send(fd, data, size, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
}

// Reads exactly `size` bytes (blocking); false at the end of the stream or on an error.
bool ReceiveAll(int fd, char* data, std::size_t size) {
  while (size > 0) {
    const ssize_t n = ::read(fd, data, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    data += n;
    size -= static_cast<std::size_t>(n);
  }
  return true;
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

IsolatedWorker::IsolatedWorker(Work work, IsolateOptions options)
    : work_(std::move(work)), options_(options) {}

IsolatedWorker::~IsolatedWorker() { Stop(); }

void IsolatedWorker::Start(const std::string& what) {
  int channel[2], err_pipe[2];
  TROCAR_THROW_UNLESS(::socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, channel) == 0,
                      what << ": cannot start the decoder process (socketpair: "
                           << std::strerror(errno) << ")");
  if (::pipe2(err_pipe, O_CLOEXEC) != 0) {
    const int e = errno;
    ::close(channel[0]);
    ::close(channel[1]);
    TROCAR_THROW(what << ": cannot start the decoder process (pipe: " << std::strerror(e) << ")");
  }
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::close(channel[0]);
    ::close(err_pipe[0]);
    to_child_ = from_child_ = channel[1];
    child_err_ = err_pipe[1];
    Serve();
  }
  ::close(channel[1]);
  ::close(err_pipe[1]);
  if (pid < 0) {
    const int e = errno;
    ::close(channel[0]);
    ::close(err_pipe[0]);
    TROCAR_THROW(what << ": cannot start the decoder process (fork: " << std::strerror(e) << ")");
  }
  pid_ = pid;
  to_child_ = from_child_ = channel[0];
  child_err_ = err_pipe[0];
  ++started_;
}

void IsolatedWorker::Serve() {
  ::signal(SIGPIPE, SIG_IGN);
  // A crash here ends this child only: no handler inherited from the parent (a fuzzer's or a
  // sanitizer's crash report, which would write artifacts and exit as if the parent had crashed).
  for (int sig : {SIGABRT, SIGSEGV, SIGBUS, SIGFPE, SIGILL, SIGTRAP, SIGALRM, SIGTERM, SIGINT}) {
    ::signal(sig, SIG_DFL);
  }
  ::dup2(child_err_, STDERR_FILENO);
  const int fd = to_child_;
  std::string request, answer;
  for (;;) {
    std::uint64_t length = 0;
    if (!ReceiveAll(fd, reinterpret_cast<char*>(&length), sizeof length)) break;  // caller done
    try {
      request.resize(length);
    } catch (...) {
      break;
    }
    if (!ReceiveAll(fd, request.data(), request.size())) break;
    answer.assign(1, kOk);
    try {
      std::string body;
      work_(request, &body);
      answer.append(body);
    } catch (const Error& e) {
      answer.assign(1, kError).append(e.what());
    } catch (const std::exception& e) {
      answer.assign(1, kException).append(e.what());
    } catch (...) {
      answer.assign(1, kException).append("an exception that is not a std::exception");
    }
    const std::uint64_t size = answer.size() <= options_.max_output_bytes + 1 ? answer.size() : kTooLong;
    if (!SendAll(fd, reinterpret_cast<const char*>(&size), sizeof size)) break;
    if (size != kTooLong && !SendAll(fd, answer.data(), answer.size())) break;
  }
  // _exit: no atexit handlers, no static destructors, no flush of the parent's stdio buffers.
  ::_exit(0);
}

void IsolatedWorker::Stop() {
  if (pid_ < 0) return;
  // Killed, not asked to leave: closing our end is not an end of file for the child when a
  // later child (another worker's) holds a copy of it, and waiting for that would hang. The
  // child holds nothing that needs a clean exit.
  ::kill(pid_, SIGKILL);
  Reap();
}

int IsolatedWorker::Reap() {
  ::close(to_child_);
  ::close(child_err_);
  int status = 0;
  while (::waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
  }
  pid_ = -1;
  to_child_ = from_child_ = child_err_ = -1;
  return status;
}

std::string IsolatedWorker::Call(const std::string& what, const std::string& request,
                                 double timeout_s) {
  if (pid_ < 0) Start(what);
  err_.clear();
  const double limit_s = timeout_s >= 0.0 ? timeout_s : options_.timeout_s;
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                            std::chrono::duration<double>(limit_s));
  // The request: its length, then its bytes. A child that has died shows as a failed send.
  const std::uint64_t length = request.size();
  bool alive = SendAll(to_child_, reinterpret_cast<const char*>(&length), sizeof length) &&
               SendAll(to_child_, request.data(), request.size());

  // The answer: 8 bytes of length, then the status byte and the body; the child's standard
  // error read alongside so that it never blocks on it.
  std::string answer;
  std::uint64_t answer_length = 0;
  std::size_t header = 0;
  bool timed_out = false, over = false;
  char buffer[65536];
  while (alive) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      timed_out = true;
      break;
    }
    pollfd fds[2] = {{from_child_, POLLIN, 0}, {child_err_, POLLIN, 0}};
    const int ready = ::poll(fds, child_err_ >= 0 ? 2 : 1,
                             static_cast<int>(std::min<long long>(left.count(), 1000)));
    if (ready < 0 && errno == EINTR) continue;
    if (ready < 0) {
      alive = false;
      break;
    }
    if (child_err_ >= 0 && fds[1].revents != 0) {
      const ssize_t n = ::read(child_err_, buffer, sizeof buffer);
      if (n > 0) {
        err_.append(buffer, static_cast<std::size_t>(n));
        if (err_.size() > 2 * kStderrTail) err_.erase(0, err_.size() - kStderrTail);
      }
    }
    if (fds[0].revents == 0) continue;
    if (header < sizeof answer_length) {
      const ssize_t n = ::read(from_child_, reinterpret_cast<char*>(&answer_length) + header,
                               sizeof answer_length - header);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        alive = false;
        break;
      }
      header += static_cast<std::size_t>(n);
      if (header < sizeof answer_length) continue;
      if (answer_length == kTooLong || answer_length > options_.max_output_bytes + 1) {
        over = true;
        break;
      }
      answer.reserve(answer_length);
      if (answer_length == 0) break;
      continue;
    }
    const std::size_t want = std::min<std::size_t>(sizeof buffer, answer_length - answer.size());
    const ssize_t n = ::read(from_child_, buffer, want);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      alive = false;
      break;
    }
    answer.append(buffer, static_cast<std::size_t>(n));
    if (answer.size() == answer_length) break;
  }

  if (timed_out) {
    Stop();
    TROCAR_THROW(what << ": the decoder did not finish within " << limit_s
                      << " s and was stopped (a damaged or hostile file?)");
  }
  if (over) {  // the child is well and goes on serving
    TROCAR_THROW(what << ": the decoder's answer is more than " << options_.max_output_bytes
                      << " bytes");
  }
  if (!alive) {
    // The child has gone: what it printed last, and how it ended.
    for (;;) {
      const ssize_t n = ::read(child_err_, buffer, sizeof buffer);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;
      err_.append(buffer, static_cast<std::size_t>(n));
    }
    if (err_.size() > kStderrTail) err_.erase(0, err_.size() - kStderrTail);
    const int status = Reap();  // it has ended: nothing to kill
    TROCAR_THROW_UNLESS(!WIFSIGNALED(status),
                        what << ": the decoder crashed on it (signal " << WTERMSIG(status) << ", "
                             << ::strsignal(WTERMSIG(status)) << ")" << Tail(err_)
                             << "; the file is damaged or uses an encoding the library cannot read");
    TROCAR_THROW(what << ": the decoder ended without an answer (exit status "
                      << (WIFEXITED(status) ? WEXITSTATUS(status) : -1) << ")" << Tail(err_));
  }
  TROCAR_THROW_UNLESS(!answer.empty(), what << ": the decoder's answer is empty");
  const char kind = answer.front();
  answer.erase(0, 1);
  if (kind == kError) internal::ThrowError(answer);
  TROCAR_THROW_UNLESS(kind == kOk, what << ": the decoder failed: " << answer);
  return answer;
}

std::string RunIsolated(const std::string& what, const std::function<void(std::string* out)>& work,
                        const IsolateOptions& options) {
  IsolatedWorker worker([&work](const std::string&, std::string* out) { work(out); }, options);
  return worker.Call(what, std::string());
}

}  // namespace trocar
