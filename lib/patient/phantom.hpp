#pragma once
/// @file
/// A procedural thorax phantom: a CT volume in Hounsfield units and its ground truth, so that
/// batches can generate patient populations and tests can check segmentation against known
/// anatomy. Patient frame LPS, metres: x toward the left, y posterior, z superior.

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "patient/curve.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {

struct PhantomParameters {
  unsigned seed = 1;              ///< jitters the anatomy within the ranges below, reproducibly
  double body_width = 0.34;       ///< m, left-right, at the skin
  double body_depth = 0.24;       ///< m, anterior-posterior, at the skin
  double length = 0.34;           ///< m, superior-inferior extent of the volume
  double fat_thickness = 0.012;   ///< m, subcutaneous fat
  double wall_thickness = 0.010;  ///< m, chest-wall muscle outside the ribs
  int ribs_per_side = 9;
  double rib_spacing = 0.028;     ///< m, between rib centres at the back
  double rib_radius = 0.0055;     ///< m, rib cross-section
  double rib_drop = 0.05;         ///< m, how much lower a rib's front end is than its back
  /// Scales the heart's semi-axes (0.074, 0.053, 0.043) m along its long, middle and short axes
  /// (`PhantomTruth::heart_axes`).
  double heart_scale = 1.0;
  Eigen::Vector3d heart_offset = Eigen::Vector3d::Zero();  ///< m, added to the heart centre
  double voxel_size = 0.002;      ///< m, in-plane (x, y)
  double slice_spacing = 0.0;     ///< m, between axial slices (0: the voxel size; clinical CT 1-3 mm)
  /// m, the square in-plane extent of the scan centred on the body, as a clinical reconstruction's
  /// field of view (0: the body and 2 cm of air around it).
  double field_of_view = 0.0;
  /// Ribs reaching the vertebral bodies at their heads (the costovertebral joints), as real ribs
  /// do; off, they stop 2 cm short of the spine.
  bool ribs_reach_spine = false;
  /// The shoulder girdle and arms: shoulder blades in the back's muscle over the upper ribs,
  /// collarbones over the first ribs, upper arms beside the chest (the field of view widens to
  /// hold them). Needs `wall_thickness` of at least 0.02 m (the shoulder blade lies in it).
  bool shoulders = false;
  /// A CT table under the back: a carbon-fibre top (two 2 mm shells 30 mm apart over foam, a
  /// cradle curved 1 m across, 0.46 m wide, cut by the field of view when wider), its top this
  /// far behind the back (m); negative presses the back flat onto it over a patch (as a patient
  /// lies on the table). NaN: no table.
  double table_gap = NAN;
};

struct PhantomTruth {
  struct Rib {
    int side;   ///< +1 left, −1 right
    int index;  ///< 0 = the highest
    Curve centreline;
  };
  std::vector<Rib> ribs;  ///< index 0 is rib 1 when the cage is whole (12 a side, top in view)
  /// Port candidate curves: the middle of each intercostal space on the skin, left side first.
  std::vector<Curve> intercostal_spaces;
  std::vector<int> intercostal_side;  ///< +1 left, −1 right, per space
  Curve lad;   ///< left anterior descending artery on the heart's anterior surface, base to apex
  Curve lima;  ///< left internal mammary (thoracic) artery inside the chest wall, top to bottom
  Eigen::Vector3d heart_centre = Eigen::Vector3d::Zero();
  /// The heart ellipsoid's semi-axes (m) along the columns of `heart_axes`.
  Eigen::Vector3d heart_semi_axes = Eigen::Vector3d::Zero();
  /// The heart ellipsoid's axes in the patient frame (columns, a rotation): the long axis from the
  /// base to the apex (left, anterior, inferior), the middle axis toward the left ventricle
  /// (left, posterior, superior), the short axis out of the sternocostal surface (anterior,
  /// superior). docs/phantom.md gives the real hearts they were measured on.
  Eigen::Matrix3d heart_axes = Eigen::Matrix3d::Identity();
  /// A patient point in the heart ellipsoid's unit coordinates: inside the heart when its norm is
  /// at most 1.
  Eigen::Vector3d HeartCoordinates(const Eigen::Vector3d& p_P) const {
    return (heart_axes.transpose() * (p_P - heart_centre)).cwiseQuotient(heart_semi_axes);
  }
  /// How far the heart reaches from its centre along a unit direction in the patient frame (m).
  double HeartReach(const Eigen::Vector3d& direction_P) const {
    return (heart_axes.transpose() * direction_P).cwiseProduct(heart_semi_axes).norm();
  }
  /// LAD surface normals (outward from the heart), one per LAD point.
  std::vector<Eigen::Vector3d> lad_normals;
};

struct Phantom {
  Volume ct;
  PhantomTruth truth;
  PhantomParameters parameters;
};

/// Tissue values (HU) used by the phantom.
struct PhantomHu {
  static constexpr float kAir = -1000, kLung = -820, kFat = -100, kMuscle = 45, kBlood = 280,
                         kMyocardium = 90, kArtery = 380, kBone = 750, kCancellous = 250,
                         kDisc = 80, kMarrow = -50, kCarbon = 600, kFoam = -950;
};

/// @throws trocar::Error for parameters out of their sensible ranges (named).
Phantom GeneratePhantom(const PhantomParameters& parameters);

/// The phantom generator's anatomy version, written into a case's truth.json. Raised whenever
/// GeneratePhantom lays out the anatomy differently for the same parameters, so that a case
/// generated on first use by an older build is generated again (PhantomCaseIsCurrent).
inline constexpr int kPhantomGeneratorVersion = 2;

/// Whether `dir/truth.json` was written by this generator version (false when it is missing,
/// unreadable or older).
bool PhantomCaseIsCurrent(const std::string& dir);

/// How a phantom case stores its CT.
enum class CtFormat {
  kNrrdLps,  ///< dir/ct.nrrd with an LPS header
  kNrrdRas,  ///< dir/ct.nrrd with a RAS header
  kDicom,    ///< dir/ct/ as a DICOM CT series, one file per axial slice
};

/// Writes the CT (`ct.nrrd` or the DICOM folder `ct/`, see CtFormat), `dir/markups/*.mrk.json`
/// (3D Slicer curves: LAD, LIMA, intercostal spaces), `dir/truth.json` (ribs) and
/// `dir/patient.yaml`, each atomically. `write_patient_yaml` false keeps an existing case file
/// (a bundled case generated on first use).
void WritePhantomCase(const Phantom& phantom, const std::string& dir,
                      CtFormat format = CtFormat::kNrrdLps, bool write_patient_yaml = true);

}  // namespace trocar::patient
