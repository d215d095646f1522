#include "common/file_util.hpp"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "common/error.hpp"

namespace trocar {

std::string ReadTextFile(const std::string& path) {
  std::error_code ec;
  TROCAR_THROW_UNLESS(std::filesystem::exists(path, ec), path << ": file not found");
  TROCAR_THROW_UNLESS(std::filesystem::is_regular_file(path, ec),
                      path << ": not a regular file");
  std::ifstream in(path, std::ios::binary);
  TROCAR_THROW_UNLESS(in.good(), path << ": cannot open for reading: " << std::strerror(errno));
  std::ostringstream buffer;
  buffer << in.rdbuf();
  TROCAR_THROW_UNLESS(!in.bad(), path << ": read error");
  return buffer.str();
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
