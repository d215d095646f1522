#pragma once
/// @file
/// Label maps from the segmentation tools our users already run: TotalSegmentator (one
/// multi-label NIfTI with its names in the header extension or in a JSON sidecar, or its folder of
/// per-structure masks; class names of versions 1 and 2) and 3D Slicer (`.seg.nrrd`, names in the
/// `SegmentN_Name` / `SegmentN_LabelValue` keys). Each named label is classified into what the
/// patient model uses: numbered ribs, sternum, costal cartilages, vertebrae, heart, vessels, and
/// the shoulder girdle and arms (which are kept out of the ribs).

#include <map>
#include <string>
#include <vector>

#include "patient/segmentation.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {

/// What a label means to the patient model.
enum class LabelKind {
  kOther,      ///< an organ trocar does not model (liver, lung, ...): not used
  kRib,        ///< with side and number
  kSternum,
  kCartilage,  ///< costal cartilages: part of the rib cage's wall, between the ribs and sternum
  kVertebra,
  kHeart,      ///< the heart, or one of its chambers or its myocardium
  kVessel,     ///< aorta, great vessels, venae cavae, pulmonary trunk and veins
  kShoulder,   ///< scapulae, clavicles, humeri: bone outside the rib cage
};

struct LabelClass {
  LabelKind kind = LabelKind::kOther;
  int side = 0;    ///< +1 left, −1 right, 0 midline or none
  int number = 0;  ///< rib number 1..12 (0 for other kinds)
};

/// Classifies a label name (case, spaces and hyphens ignored): TotalSegmentator v1/v2 names
/// (rib_left_5, vertebrae_T7, heart_ventricle_left, clavicula_left, ...) and common spellings
/// ("Rib left 5", "left rib 5", "rib_5_left", "sternum").
LabelClass ClassifyLabel(const std::string& name);

struct LabelMap {
  Volume volume;                    ///< label values on the map's own grid
  std::map<int, std::string> names;  ///< label value → name
  std::string source;               ///< file or folder
};

/// Reads a label map: a folder of masks (each `<name>.nii.gz`/`.nii`/`.nrrd` a structure), a
/// `.seg.nrrd` (3D Slicer, one layer), or any volume with its names in a NIfTI header extension
/// (TotalSegmentator's Caret XML label table) or in a JSON sidecar ({"value": "name"}; `names`, or
/// the file's name with `.json` in place of `.nii.gz`/`.nii`/`.nrrd`).
/// @throws trocar::Error naming the file: no names found, names that are not label values,
///         multi-layer segmentations, masks on different grids in one folder.
LabelMap LoadLabelMap(const std::string& path, const std::string& names = "");

/// The label map's values on `grid`, nearest voxel through both volumes' patient geometry
/// (0 outside the map). @throws trocar::Error naming both geometries when they do not overlap.
std::vector<int> ResampleLabels(const LabelMap& map, const Volume& grid);

/// What a label map gives the model on the CT's grid.
struct LabelledAnatomy {
  BoneParts bones;         ///< ribs numbered (Component::number, side), sternum (+ cartilages), spine
  Mask heart, vessels, shoulder;
  std::vector<std::string> used, unused;  ///< label names, by whether the model uses them
};

/// Builds bone parts (one component per labelled rib, sternum, costal cartilages and the
/// vertebrae), heart, vessel and shoulder masks from a label map on `ct`'s grid.
/// @throws trocar::Error listing the names when none of the labels is a structure trocar uses.
LabelledAnatomy AnatomyFromLabels(const LabelMap& map, const Volume& ct);

/// How well a label map's ribs lie on the CT's ribs (issue #42, bad input): the share of the
/// labelled rib voxels whose CT value is bone-bright (above `bone_threshold`, in the CT's units)
/// where the map puts them, and the best share with the labels moved 5 to 30 mm (in 5 mm steps)
/// along any of the grid's axes. A map of this CT is best where it is; a map shifted by half a rib
/// or more, or another patient's, lies better moved or nowhere.
struct LabelAgreement {
  long rib_voxels = 0;
  double here = 0.0;  ///< share bone-bright, unmoved
  double best = 0.0;  ///< the best share over the moves (and unmoved)
  Eigen::Vector3d best_move_P = Eigen::Vector3d::Zero();  ///< the move giving it (m)
};
LabelAgreement MeasureLabelAgreement(const Volume& ct, const BoneParts& bones,
                                     double bone_threshold);

}  // namespace trocar::patient
