#pragma once
/// @file
/// File helpers: reading with errors that name the file, and atomic writes (temporary name,
/// then rename) so that no reader ever sees a half-written output.

#include <string>

namespace trocar {

/// Whole file as text. @throws trocar::Error naming the path when it cannot be read.
std::string ReadTextFile(const std::string& path);

/// Writes `content` to `path` through a temporary file in the same folder and a rename.
/// @throws trocar::Error naming the path when any step fails; the target is then untouched.
void WriteFileAtomically(const std::string& path, const std::string& content);

/// True when `path` names an existing regular file.
bool IsRegularFile(const std::string& path);

/// Folder part of a path ("." when there is none).
std::string ParentDirectory(const std::string& path);

/// `relative` resolved against `base_dir` unless it is already absolute.
std::string JoinPath(const std::string& base_dir, const std::string& relative);

}  // namespace trocar
