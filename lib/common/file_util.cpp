#include "common/file_util.hpp"

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "common/error.hpp"
#include "common/limits.hpp"

namespace trocar {

std::string ReadTextFile(const std::string& path) {
  return ReadFileBounded(path, Limits().max_text_bytes, "TROCAR_MAX_TEXT_BYTES");
}

std::string ReadBinaryFile(const std::string& path) {
  return ReadFileBounded(path, Limits().max_file_bytes, "TROCAR_MAX_FILE_BYTES");
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

void WriteFileAtomically(const std::string& path, const std::string& content) {
  namespace fs = std::filesystem;
  const fs::path target(path);
  std::random_device rd;
  const fs::path temp = target.parent_path() /
                        (target.filename().string() + ".tmp" + std::to_string(rd() % 1000000));
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    TROCAR_THROW_UNLESS(out.good(), temp.string() << ": cannot open for writing: "
                                                  << std::strerror(errno));
    out << content;
    out.flush();
    if (!out.good()) {
      std::error_code ignored;
      fs::remove(temp, ignored);
      TROCAR_THROW(temp.string() << ": write failed: " << std::strerror(errno));
    }
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
