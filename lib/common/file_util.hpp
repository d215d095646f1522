#pragma once
/// @file
/// File helpers: reading with errors that name the file, and atomic writes (temporary name,
/// then rename) so that no reader ever sees a half-written output.

#include <cstdint>
#include <string>

namespace trocar {

/// Whole file as text. @throws trocar::Error naming the path when it cannot be read.
/// Refused beyond `Limits().max_text_bytes` (TROCAR_MAX_TEXT_BYTES), before anything is read.
std::string ReadTextFile(const std::string& path);

/// Whole binary file (CT data, the model cache), refused beyond `Limits().max_file_bytes`.
std::string ReadBinaryFile(const std::string& path);

/// Whole file, refused (naming the file, its size, the limit and `env`) beyond `max_bytes`.
std::string ReadFileBounded(const std::string& path, std::uint64_t max_bytes, const char* env);

/// Writes `content` to `path` through a temporary file in the same folder
/// ("<name>.tmp.<pid>.<n>", created exclusively) and a rename. First removes
/// the temporaries of `path` whose writer process is gone (a write killed half-way), and only
/// those.
/// @throws trocar::Error naming the path when any step fails; the target is then untouched.
void WriteFileAtomically(const std::string& path, const std::string& content);

/// True when `path` names an existing regular file.
bool IsRegularFile(const std::string& path);

/// Folder part of a path ("." when there is none).
std::string ParentDirectory(const std::string& path);

/// `relative` resolved against `base_dir` unless it is already absolute.
std::string JoinPath(const std::string& base_dir, const std::string& relative);

}  // namespace trocar
