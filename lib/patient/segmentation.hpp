#pragma once
/// @file
/// Segmentation with no manual work: body (skin) and bone (ribs, sternum, spine) from
/// thresholds and connected components, the heart from a mask volume. Thresholds are Hounsfield
/// units, or raw values for windowed volumes such as 8-bit CT.

#include <optional>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "patient/anatomy.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {

/// A binary mask on a volume's grid (same size and geometry as the volume it came from).
struct Mask {
  Eigen::Vector3i size = Eigen::Vector3i::Zero();
  std::vector<std::uint8_t> inside;
  long count() const;
};

/// The index axis that runs most nearly along the patient's z (superior): the scan's slices lie
/// across it.
int AxialAxis(const Volume& v);

/// The spacings along the two index axes across AxialAxis (m): a slice's rows and columns,
/// whichever index axes the file stores them along (a volume stored sagittally has its slices
/// across its first axis).
Eigen::Vector2d InPlaneSpacing(const Volume& v);

struct Component {
  int label = 0;           ///< 1-based label in the label image
  long voxels = 0;
  double volume = 0.0;     ///< m³
  Eigen::Vector3d centroid_P = Eigen::Vector3d::Zero();
  Eigen::Vector3d min_P = Eigen::Vector3d::Zero(), max_P = Eigen::Vector3d::Zero();  ///< bounds
  int number = 0;          ///< anatomical rib number (1 = under the collarbone) when known, else 0
};

/// 26-connected components of a mask, largest first; labels[i] is 0 outside, else the label.
/// With `region`, neighbours join only when their region values are equal (a cut along the
/// regions' borders).
std::vector<Component> ConnectedComponents(const Volume& grid, const Mask& mask,
                                           std::vector<int>* labels,
                                           const std::vector<std::uint8_t>* region = nullptr);

struct SegmentationOptions {
  /// Thresholds: in HU for Hounsfield volumes; the `raw_` ones for others (e.g. 8-bit windowed).
  double body_hu = -400.0;
  double bone_hu = 450.0;  // above contrast-filled blood (250-400 HU)
  double raw_body = 40.0;
  double raw_bone = 160.0;  // 8-bit windowed CT: cortical bone is 160-255
  /// Closing radius (m) applied to the body before filling: windowed volumes clip fat to the
  /// value of air, which breaks the body's outline; a closing bridges those gaps.
  double body_closing = 0.0;
  double raw_body_closing = 0.006;
  /// Fill each axial slice's convex hull instead of its holes (windowed volumes, whose outline
  /// stays broken).
  bool body_convex_fill = false;
  bool raw_body_convex_fill = true;
  /// ... unless the outline held: when filling each slice's holes gives at least this share of
  /// the convex fill's volume, the holes' fill is kept (its concavities are real: an arm beside
  /// the chest, the back). A broken outline leaves the lungs open to the outside (LIDC2: 27 %).
  double convex_fill_below = 0.6;
  /// A CT table (or a pad, a blanket) joined to the body is left out of it (Hounsfield volumes;
  /// in a windowed one fat reads as air and the skin over it is as thin): a piece of the body
  /// thinner than twice `table_thickness` (m; it vanishes when the body is eroded by a ball of
  /// that radius) of at least `table_min_volume` (m³) that runs through at least
  /// `table_min_slices` of the body's slices with the same cross-section (at least
  /// `table_constant` of its voxels at in-plane places it holds in 80 % of its slices: the table
  /// does not change along the scan, the body does), and the bright voxels by which it lies
  /// against the back. Worked on blocks of at most `table_grid` (m) in-plane and about
  /// `table_grid_slices` along the slices. `table_thickness` 0 turns it off.
  double table_thickness = 0.005;
  double table_min_volume = 5e-6;
  double table_min_slices = 0.9, table_constant = 0.7;
  double table_grid = 0.0015, table_grid_slices = 0.0025;
  /// Bone components smaller than this are noise (m³).
  double min_bone_volume = 0.3e-6;
  /// Bone sorted by shape and place (ClassifyBones, anatomy.hpp): contrast kept out of the bone,
  /// ribs cut from the spine, the shoulder girdle kept out of the ribs, pieces of one rib cut by a
  /// crop face joined, ribs numbered. Off (patient.yaml `bones: place`), bone components are
  /// sorted by where they lie in the body's bounding box, as before.
  bool shape_anatomy = true;
  AnatomyOptions anatomy;
};

struct BoneParts {
  std::vector<Component> ribs_left, ribs_right;  ///< top to bottom
  std::vector<Component> spine, sternum;         ///< midline pieces
  std::vector<int> labels;                       ///< component labels on the grid
  /// Ribs carry their anatomical numbers (from a label map): spaces are named by them.
  bool numbered = false;
};

struct Segmentation {
  Mask body;  ///< the patient, holes (lungs, airways) filled
  Eigen::Vector3d body_min_P = Eigen::Vector3d::Zero();  ///< the body's bounding box (m)
  Eigen::Vector3d body_max_P = Eigen::Vector3d::Zero();
  /// The body's axis in the axial plane (m): the rays of the rib cage run from it. The spine's
  /// midline left-right when the anatomy is sorted by shape, else the bounding box's centre.
  Eigen::Vector2d axis_P = Eigen::Vector2d::Zero();
  Mask bone;
  BoneParts bones;
  /// Bright blobs inside the bone threshold that are not bone: contrast-filled heart chambers,
  /// aorta and great vessels (empty when none were found).
  Mask vessels;
  /// The shoulder girdle and arms (scapulae, clavicles, humeri): bone kept out of the ribs.
  Mask shoulder;
  double contrast_volume = 0.0;  ///< m³ of contrast-filled blood brighter than the bone threshold
  bool contrast = false;         ///< a contrast-filled blood pool was found (HU volumes)
  RibNumbering numbering_left, numbering_right;
  std::vector<std::string> anatomy;  ///< what the sorting found, in words
  double body_threshold = 0.0, bone_threshold = 0.0;  ///< as used, in the volume's units
  std::string body_fill;  ///< how the body's slices were filled, and why
  std::string body_table;  ///< a CT table joined to the body and left out of it (else empty)
};

/// Segments body and bone, and sorts the bone into anatomy by shape and place (ClassifyBones):
/// ribs (left, right; top to bottom, numbered when the top or bottom of the rib cage is in
/// view), sternum, spine, vessels and the shoulder girdle.
/// @throws trocar::Error naming the volume when the body or the bone comes out empty.
Segmentation Segment(const Volume& ct, const SegmentationOptions& options = {});

/// The patient's roll about the long axis in the scanner: how far the principal axis of the
/// body's cross-section (its width, left to right, the longer one in a chest or an abdomen) is
/// turned from the scan's left-right axis.
struct BodyRoll {
  /// rad about +z_P, in (−π/2, π/2]: positive turns the left side toward the back (LPS), down
  /// for a patient lying on the back.
  double angle = 0.0;
  double aspect = 1.0;  ///< the cross-section's width over its depth (square root of the ratio of
                        ///< the principal moments)
  Eigen::Vector3d centre_P = Eigen::Vector3d::Zero();  ///< the body's centroid
};

/// The body mask's second moments in the axial plane, over all its voxels.
BodyRoll MeasureBodyRoll(const Volume& ct, const Mask& body);

/// How far the grid's index axes are turned from the patient's axes (rad): the largest angle
/// between an index axis and the patient axis nearest it. 0 for a grid along the patient's axes
/// in any order and sense (a sagittal stack, a mirrored axis); an oblique reconstruction, a header
/// written after a registration or a gantry tilt (slices sheared along the table) turn them.
double GridObliquity(const Volume& v);

/// Moves a volume's geometry by X_DP: the same voxels, their patient points mapped into frame D.
void MoveVolumeFrame(const Eigen::Isometry3d& X_DP, Volume* v);

/// The volume resampled (nearest voxel: its values as they are) onto a grid whose axes are frame
/// D's, which X_DP turns about z_P: the original's in-plane spacing (the finer one) and its
/// slices, over the voxels of `cover` (a mask on `v`; null: the whole of it) turned into D and
/// `margin` voxels around them in-plane; `fill` outside the original. Its slices are as far apart
/// along z as the original's (a sheared, gantry-tilted stack comes out along z). Its geometry maps
/// into D (`index_to_P`, `origin_P`).
Volume ResampleTurned(const Volume& v, const Eigen::Isometry3d& X_DP, float fill,
                      const Mask* cover = nullptr, int margin = 8);

/// A mask from another volume (e.g. TotalSegmentator's heart.nii.gz) resampled, nearest voxel,
/// onto `grid` through both volumes' patient geometry. @throws trocar::Error when the mask does
/// not overlap the grid at all.
Mask ResampleMask(const Volume& mask_volume, const Volume& grid, double threshold = 0.5);

/// Squared Euclidean distance (m²) from every voxel's centre to the nearest voxel inside `mask`
/// (0 inside), exact, in linear time (Felzenszwalb and Huttenlocher's lower envelope per axis,
/// with each axis' spacing; index axes are taken as orthogonal).
std::vector<float> SquaredDistanceToMask(const Volume& grid, const Mask& mask);

struct HeartOptions {
  /// Contrast-filled blood: above these (and below the bone threshold). HU, or raw for windowed
  /// volumes (8-bit contrast CT: blood 100-150, myocardium 40-80, fat near 0).
  double blood_hu = 150.0, raw_blood = 100.0;
  /// Brightest blood (HU; strong pulmonary-angiography contrast reaches 600). For raw volumes the
  /// bone threshold.
  double blood_max_hu = 700.0;
  /// Soft tissue the heart wall may grow into around the blood pool.
  double soft_hu = -30.0, raw_soft = 30.0;
  /// Opening radius separating the cardiac chambers from the great vessels (m).
  double opening_radius = 0.008;
  /// Other chamber blobs joined to the largest: at least this share of its volume, centroid
  /// within this distance of its centroid (m).
  double min_chamber_fraction = 0.05;
  double chamber_reach = 0.07;
  /// Blobs whose bounding box is this many times longer than wide are vessels, not chambers.
  double max_chamber_elongation = 3.0;
  /// Myocardium grown around the blood pool (m).
  double wall_thickness = 0.008;
};

/// The heart in a contrast CT without a mask: contrast-filled blood inside the body; an opening
/// by a ball of `opening_radius` separates the chambers from the vessels; the largest chamber
/// blob in the chest and the sizeable blobs around it are grown back within the blood, then by the
/// wall thickness into soft tissue.
/// @throws trocar::Error naming the volume when no blood pool is found (not a contrast CT: give
///         the heart as a mask file instead).
Mask SegmentHeartFromContrast(const Volume& ct, const Segmentation& seg,
                              const HeartOptions& options = {});

/// As SegmentHeartFromContrast, but no blood pool (a CT without contrast) is nullopt, not an
/// error: contrast is detected, not declared.
std::optional<Mask> TrySegmentHeartFromContrast(const Volume& ct, const Segmentation& seg,
                                                const HeartOptions& options = {});

/// The heart approximated without contrast: soft tissue between the lungs (lung on both sides
/// along the row) in front of the lungs' centre, opened by a 15 mm ball, the largest blob grown
/// back. It holds the heart with the great vessels' roots and mediastinal tissue around them, an
/// over-estimate that planning avoids; the import flags it as an approximation.
/// @throws trocar::Error naming the volume when no lungs or no such tissue is found.
Mask ApproximateHeartFromMediastinum(const Volume& ct, const Segmentation& seg,
                                     const HeartOptions& options = {});

}  // namespace trocar::patient
