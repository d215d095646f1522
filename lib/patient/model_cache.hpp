#pragma once
/// @file
/// The model's cache beside its case (`<case>/cache/`): the key over every input file's contents,
/// the list of the CT's files (so a cached load need not decode the CT), and the files written
/// (model.bin last, atomically; one STL per structure; targets and candidates as markups).
/// Serialisation itself is declared in patient_model.hpp.

#include <cstdint>
#include <string>
#include <vector>

#include "patient/case_file.hpp"
#include "patient/patient_model.hpp"

namespace trocar::patient {

/// The checksum model.bin carries over everything before it (its last 16 bytes are this
/// checksum and the end marker). Exposed for the cache's fuzz target, which seals mutated bytes
/// so that the parser behind the checksum is explored too.
std::uint64_t ModelChecksum(const char* data, std::size_t n);

/// The files of a folder, sorted. @throws trocar::Error when it cannot be listed.
std::vector<std::string> FolderFiles(const std::string& dir);

/// The cache key: FNV-1a over a format version, the name and contents of every file the model
/// depends on (the case file, the CT's files `ct_files` as the CT reader read them, masks, label
/// maps, markups) and, for a DICOM CT, the listing (names, sizes) of the folder its series is
/// chosen from. @throws trocar::Error when an input cannot be read.
std::uint64_t CacheKey(const CaseSpec& c, const std::vector<std::string>& ct_files);

/// The SHA-256 (hex) of the model-building code (lib/patient, the mesh code) this build was made
/// from; part of CacheKey, so a cache written by other code is rebuilt, never trusted.
const char* PatientModelCode();

/// `cache/ct_files.txt`: the CT's files as the last build read them; empty when absent, damaged
/// or naming a file that is gone.
std::vector<std::string> ReadCtFiles(const std::string& cache_dir);

/// Writes the cache folder; model.bin last. @throws trocar::Error when it cannot be written.
void WriteCacheFiles(const PatientModel& m, const ImportReport& report, const std::string& cache_dir,
                     std::uint64_t key, const std::vector<std::string>& ct_files);

}  // namespace trocar::patient
