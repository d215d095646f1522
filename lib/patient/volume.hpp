#pragma once
/// @file
/// A CT volume in the patient frame. The patient frame P is LPS (x toward the patient's left,
/// y posterior, z superior, as DICOM) in metres; every reader converts once, at import (NIfTI's
/// RAS by negating x and y; millimetres to metres).

#include <string>
#include <utility>
#include <vector>

#include "common/image.hpp"

#include <Eigen/Geometry>

namespace trocar::patient {

/// Metres in a millimetre: the file formats give spacings and positions in mm, trocar works in m.
inline constexpr double kMillimetre = 1e-3;

struct Volume {
  Eigen::Vector3i size = Eigen::Vector3i::Zero();  ///< voxels along i, j, k
  /// Patient position of voxel (i, j, k): p_P = origin_P + index_to_P · (i, j, k). Columns are
  /// the index axes' directions times the spacing (m).
  Eigen::Matrix3d index_to_P = Eigen::Matrix3d::Identity();
  Eigen::Vector3d origin_P = Eigen::Vector3d::Zero();  ///< m, centre of voxel (0, 0, 0)
  std::vector<float> values;   ///< i fastest, then j, then k
  bool hounsfield = false;     ///< values are Hounsfield units (else raw, e.g. 8-bit windowed)
  std::string source;          ///< file (or DICOM folder) it came from
  std::vector<std::string> files;  ///< every file read (header, detached data, DICOM slices)
  /// Metadata a label map carries its names in: NIfTI-1 header extensions (ecode, content) and
  /// NRRD key/value pairs (`key:=value`, e.g. a 3D Slicer segmentation's Segment0_Name).
  std::vector<std::pair<int, std::string>> extensions;
  std::vector<std::pair<std::string, std::string>> key_values;
  /// What the reader repaired or doubts, each naming the file (e.g. a NIfTI quaternion
  /// normalised); the import passes them on as the model's warnings.
  std::vector<std::string> warnings;

  long voxel_count() const { return static_cast<long>(size.x()) * size.y() * size.z(); }
  long Index(int i, int j, int k) const {
    return i + static_cast<long>(size.x()) * (j + static_cast<long>(size.y()) * k);
  }
  float at(int i, int j, int k) const { return values[Index(i, j, k)]; }
  Eigen::Vector3d PatientPoint(double i, double j, double k) const {
    return origin_P + index_to_P * Eigen::Vector3d(i, j, k);
  }
  /// Voxel size along each index axis (m).
  Eigen::Vector3d spacing() const { return index_to_P.colwise().norm(); }
  /// (i, j, k) of a patient point, continuous.
  Eigen::Vector3d IndexOf(const Eigen::Vector3d& p_P) const {
    return index_to_P.inverse() * (p_P - origin_P);
  }
};

/// Refuses sizes that are not positive or not finite geometry, degenerate voxel axes, and
/// voxel sizes outside 1 µm – 100 mm along any axis (a damaged header, or metres read as
/// millimetres). @throws trocar::Error naming `what`, the axis and the value.
void CheckVolumeGeometry(const Volume& volume, const std::string& what);

/// A grey-level picture of one slice: axis 2 (axial, k fixed), 1 (coronal, j fixed) or 0
/// (sagittal, i fixed), windowed to [level − width/2, level + width/2], one pixel per voxel
/// (stretched to the voxel aspect), anterior up in axial slices, superior up otherwise.
Image RenderSlice(const Volume& volume, int axis, int index, double level, double width);

/// Reads a CT volume by its extension: .nrrd/.nhdr (raw or gzip, attached or detached data),
/// .nii/.nii.gz (NIfTI-1, sform or qform), .mha/.mhd (MetaImage, raw or zlib); a folder or a
/// .dcm file is read as a DICOM series (LoadDicomSeries).
/// @throws trocar::Error naming the file and the header field or what is wrong with the data:
///         unknown type, wrong sizes, truncated or garbled data, missing data file, NaN values.
Volume LoadVolume(const std::string& path);

/// CT numbers stored without their rescale intercept (a NRRD or NIfTI written from a DICOM
/// series' stored pixel values, whose RescaleIntercept of −1024 was not applied): no value below
/// zero, air reading near 0 and the body's soft tissue near 1024 (water), bone beyond 1500. True
/// when at least 5 % of the voxels read at most 300 (air, lung) and at least 40 % of the rest
/// read 850-1200 (fat to muscle, −174 to +176 HU); `soft_tissue` gets the median of those.
/// An 8-bit window never qualifies (no value beyond 255).
bool LooksLikeCtNumbersWithoutIntercept(const Volume& v, double* soft_tissue = nullptr);

/// Reads a DICOM series through GDCM: `path` is a folder holding one series, or one file of the
/// series to pick (its folder may hold others). Every transfer syntax GDCM decodes (implicit or
/// explicit VR, big endian, deflated, JPEG, JPEG-LS, JPEG 2000, RLE); classic single-frame slices
/// or enhanced multi-frame files (frames from the functional groups). Each file's structure is
/// walked and its pixel module checked before GDCM reads it (docs/decisions.md). Slices are sorted
/// along the orientation's normal and must be evenly spaced (a gantry tilt gives an oblique third
/// axis, kept); rescale slope and intercept are applied per slice or frame (Hounsfield units for
/// CT). Non-DICOM files in the folder are skipped unread.
/// @throws trocar::Error naming the file and the element: missing geometry, a syntax GDCM cannot
///         decode (by name), mixed sizes or orientations, duplicate or missing slices, damaged or
///         truncated files, several series in the folder (listed).
Volume LoadDicomSeries(const std::string& path);

struct DicomWriteOptions {
  bool implicit_vr = false;  ///< implicit VR little endian (else explicit)
  std::string patient_name = "TROCAR^PHANTOM";
  std::string patient_id = "trocar";
  std::string series_description = "trocar volume";
};

/// Writes a volume as a DICOM CT series (one 16-bit file per slice along k, values kept when
/// they are integers in range, else rescaled) into `folder`, which must not exist or be empty;
/// written beside it first, then renamed. UIDs derive from the content: same volume, same files.
void WriteDicomSeries(const Volume& volume, const std::string& folder, const DicomWriteOptions& options = {});

/// Writes a volume as NRRD (gzip, attached header) in the LPS or RAS space, atomically.
void WriteNrrd(const Volume& volume, const std::string& path, bool ras = false);

}  // namespace trocar::patient
