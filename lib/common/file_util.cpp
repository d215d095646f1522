#include "common/file_util.hpp"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include <fcntl.h>
#include <signal.h>
#include <sys/types.h>
#include <unistd.h>

#include "common/error.hpp"
#include "common/limits.hpp"

namespace trocar {

std::string ReadTextFile(const std::string& path) {
  return ReadFileBounded(path, Limits().max_text_bytes, "TROCAR_MAX_TEXT_BYTES");
}

std::string ReadBinaryFile(const std::string& path) {
  return ReadFileBounded(path, Limits().max_file_bytes, "TROCAR_MAX_FILE_BYTES");
}

std::uint64_t RegularFileSize(const std::string& path) {
  std::error_code ec;
  TROCAR_THROW_UNLESS(std::filesystem::exists(path, ec), path << ": file not found");
  TROCAR_THROW_UNLESS(std::filesystem::is_regular_file(path, ec), path << ": not a regular file");
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  TROCAR_THROW_UNLESS(!ec, path << ": cannot read its size: " << ec.message());
  return size;
}

std::string ReadFilePrefix(const std::string& path, std::size_t max_bytes) {
  const std::uint64_t size = RegularFileSize(path);
  std::ifstream in(path, std::ios::binary);
  TROCAR_THROW_UNLESS(in.good(), path << ": cannot open for reading: " << std::strerror(errno));
  std::string content(static_cast<std::size_t>(std::min<std::uint64_t>(size, max_bytes)), '\0');
  in.read(content.data(), static_cast<std::streamsize>(content.size()));
  content.resize(static_cast<std::size_t>(in.gcount()));
  TROCAR_THROW_UNLESS(!in.bad(), path << ": read failed: " << std::strerror(errno));
  return content;
}

std::string ReadFileBounded(const std::string& path, std::uint64_t max_bytes, const char* env) {
  std::error_code ec;
  TROCAR_THROW_UNLESS(std::filesystem::exists(path, ec), path << ": file not found");
  TROCAR_THROW_UNLESS(std::filesystem::is_regular_file(path, ec),
                      path << ": not a regular file");
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  TROCAR_THROW_UNLESS(!ec, path << ": cannot read its size: " << ec.message());
  TROCAR_THROW_UNLESS(size <= max_bytes, path << ": " << size << " bytes, more than trocar reads "
                                              << LimitHint(max_bytes, env));
  std::ifstream in(path, std::ios::binary);
  TROCAR_THROW_UNLESS(in.good(), path << ": cannot open for reading: " << std::strerror(errno));
  std::string content(static_cast<std::size_t>(size), '\0');
  // Read in pieces: one istream::read of more than 2 GiB stops short on some libraries.
  std::size_t done = 0;
  while (done < content.size()) {
    const std::size_t piece = std::min<std::size_t>(content.size() - done, std::size_t{1} << 30);
    in.read(&content[done], static_cast<std::streamsize>(piece));
    const auto got = static_cast<std::size_t>(in.gcount());
    done += got;
    if (got < piece) break;
  }
  TROCAR_THROW_UNLESS(done == content.size() && !in.bad(),
                      path << ": read " << done << " of its " << content.size()
                           << " bytes (the file changed or the read failed)");
  // A file still growing is not what its size said: read what is there, but never more.
  return content;
}

namespace {

// A temporary's name: "<target>.tmp.<pid>.<n>", so that a later writer of the same target can
// tell whose it is and whether its writer still runs.
std::string TemporaryPrefix(const std::filesystem::path& target) {
  return target.filename().string() + ".tmp.";
}

}  // namespace

std::string TemporaryName(const std::string& target) {
  namespace fs = std::filesystem;
  static std::atomic<unsigned> counter{0};
  std::random_device rd;
  const fs::path t(target);
  return (t.parent_path() / (TemporaryPrefix(t) + std::to_string(::getpid()) + "." +
                             std::to_string(counter++) + "-" + std::to_string(rd() % 1000000)))
      .string();
}

void RemoveStaleTemporaries(const std::filesystem::path& target) {
  namespace fs = std::filesystem;
  const fs::path dir = target.parent_path().empty() ? fs::path(".") : target.parent_path();
  const std::string prefix = TemporaryPrefix(target);
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string rest = name.substr(prefix.size());
    const std::size_t dot = rest.find('.');
    if (dot == 0 || dot == std::string::npos) continue;
    const std::string pid_text = rest.substr(0, dot);
    if (pid_text.size() > 9 ||
        !std::all_of(pid_text.begin(), pid_text.end(), [](char c) { return c >= '0' && c <= '9'; }))
      continue;
    const pid_t pid = static_cast<pid_t>(std::stol(pid_text));
    if (pid <= 0 || pid == ::getpid()) continue;
    if (::kill(pid, 0) == 0 || errno != ESRCH) continue;  // alive (or not ours to judge)
    std::error_code ignored;
    fs::remove_all(it->path(), ignored);  // a file, or a folder written as one (a phantom case)
  }
}

void WriteFileAtomically(const std::string& path, const std::string& content) {
  namespace fs = std::filesystem;
  const fs::path target(path);
  RemoveStaleTemporaries(target);
  static std::atomic<unsigned> counter{0};
  std::random_device rd;
  fs::path temp;
  int fd = -1;
  for (int attempt = 0; attempt < 16 && fd < 0; ++attempt) {
    temp = target.parent_path() /
           (TemporaryPrefix(target) + std::to_string(::getpid()) + "." +
            std::to_string(counter++) + "-" + std::to_string(rd() % 1000000));
    // Exclusive: never another writer's temporary.
    fd = ::open(temp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    if (fd < 0 && errno != EEXIST) break;
  }
  TROCAR_THROW_UNLESS(fd >= 0, temp.string() << ": cannot open for writing: "
                                             << std::strerror(errno));
  auto fail = [&](const char* what) {
    const int saved = errno;
    ::close(fd);
    std::error_code ignored;
    fs::remove(temp, ignored);
    TROCAR_THROW(temp.string() << ": " << what << ": " << std::strerror(saved) << " (" << path
                               << " is unchanged)");
  };
  const char* data = content.data();
  std::size_t left = content.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, data, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      fail("write failed");
    }
    data += n;
    left -= static_cast<std::size_t>(n);
  }
  if (::close(fd) != 0) {
    std::error_code ignored;
    fs::remove(temp, ignored);
    TROCAR_THROW(temp.string() << ": close failed: " << std::strerror(errno));
  }
  std::error_code ec;
  fs::rename(temp, target, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(temp, ignored);
    TROCAR_THROW(path << ": cannot rename temporary file into place: " << ec.message());
  }
}

bool IsRegularFile(const std::string& path) {
  std::error_code ec;
  return std::filesystem::is_regular_file(path, ec);
}

std::string ParentDirectory(const std::string& path) {
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  return parent.empty() ? std::string(".") : parent.string();
}

std::string JoinPath(const std::string& base_dir, const std::string& relative) {
  const std::filesystem::path rel(relative);
  if (rel.is_absolute()) return rel.lexically_normal().string();
  return (std::filesystem::path(base_dir) / rel).lexically_normal().string();
}

}  // namespace trocar
