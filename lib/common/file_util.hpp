#pragma once
/// @file
/// File helpers: reading with errors that name the file, and atomic writes (temporary name,
/// then rename) so that no reader ever sees a half-written output.

#include <cstdint>
#include <filesystem>
#include <string>

namespace trocar {

/// Whole file as text. @throws trocar::Error naming the path when it cannot be read.
/// Refused beyond `Limits().max_text_bytes` (TROCAR_MAX_TEXT_BYTES), before anything is read.
std::string ReadTextFile(const std::string& path);

/// Whole binary file (CT data, the model cache), refused beyond `Limits().max_file_bytes`.
std::string ReadBinaryFile(const std::string& path);

/// Whole file, refused (naming the file, its size, the limit and `env`) beyond `max_bytes`.
std::string ReadFileBounded(const std::string& path, std::uint64_t max_bytes, const char* env);

/// At most the first `max_bytes` of a file (a header read before the data it describes, so that
/// the data's declared size can be checked against the file before the data is read).
/// @throws trocar::Error naming the file when it is missing or unreadable.
std::string ReadFilePrefix(const std::string& path, std::size_t max_bytes);

/// A fresh temporary name beside `target` ("<target>.tmp.<pid>.<n>-<r>"), for a file or a folder
/// that is written whole and then renamed into place.
std::string TemporaryName(const std::string& target);

/// Removes the temporaries of `target` (files or folders named as TemporaryName names them) whose
/// writer process is gone (killed while writing): only this target's, only when the process that
/// made one no longer exists. WriteFileAtomically calls it before each write.
void RemoveStaleTemporaries(const std::filesystem::path& target);

/// The size of a regular file in bytes. @throws trocar::Error naming the file.
std::uint64_t RegularFileSize(const std::string& path);

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
