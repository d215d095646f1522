#pragma once
/// @file
/// Bone sorted into anatomy by shape and place, not by brightness alone (docs/decisions.md,
/// "Anatomy by shape"): contrast-filled heart chambers and vessels (bright blobs thicker than any
/// rib) are vessels, never bone; the spine is the column about its axis, and ribs joined to it at
/// the costovertebral joints are cut off at the column's edge; bone lying outside the rib cage
/// (shoulder blades, collarbones, arms) is the shoulder girdle; the sternum is the rib cage's
/// anterior midline; the ribs are what remains, numbered from rib 1 or rib 12 when the top or
/// the bottom of the rib cage is in view, with a confidence.

#include <cmath>
#include <string>
#include <vector>

namespace trocar::patient {

struct Volume;
struct Segmentation;
struct LayerChart;

struct AnatomyOptions {
  /// Bone this thick (a ball of this radius fits in it) and off the spine's column is a
  /// contrast-filled heart chamber or vessel: ribs, sternum, collarbones and shoulder blades are
  /// thinner (m).
  double vessel_core_radius = 0.007;
  /// ... in a windowed (raw) volume; and the thinner core used there instead when the ribs, as
  /// sorted with it, hold a ball of that radius in under `raw_cortex_rib_share` of their voxels
  /// (0: never): then only a bone's cortex reaches the bone threshold (the marrow lies below
  /// it), a few millimetres of cortex are the thickest bone off the spine's column, and the
  /// undiluted contrast of an injection (the arm's veins, the superior vena cava, the right
  /// heart: LIDC2's "sternum" before) is thinner than 7 mm in places. A window wide enough that
  /// ribs read solid (the phantom's: 77-91 % of their voxels hold one) keeps 7 mm.
  double raw_vessel_core_radius = 0.007;
  double raw_cortex_core_radius = 0.0035;
  double raw_cortex_rib_share = 0.05;
  double raw_cortex_cell = 0.0014;  ///< the share is measured on cells at least this wide (m)
  /// A scan without contrast (no blood pool of at least `contrast_min_volume` m³ and
  /// `contrast_bone_ratio` of the bone's volume) takes its bone threshold from the first of these
  /// (HU) instead: thin ribs and coarse slices' partial-volume bone stay in.
  std::vector<double> plain_bone_hu = {250.0};
  /// A scan with contrast whose bone, at the bone threshold (above the blood), holds ribs on both
  /// sides but no sternum is sorted again with its bone taken from this level (HU), within the
  /// blood's range: a coarse slice's thin ribs and sternum read under the blood's brightest
  /// (lidc-idri-0001's labelled sternum: median 146 HU, 90th percentile 383; its ribs 2-4 under
  /// 415 at the 90th). Thick blood is sorted out by its thickness as before (0: never).
  double enhanced_bone_hu = 300.0;
  /// Below `enhanced_seed_hu` (HU), a rib or sternum piece must hold a voxel above it: a bone's
  /// cortex reads above it somewhere along its length, where contrast in a vessel too thin to be
  /// found as a pool (a coronary artery on the heart, a mammary artery) stays at the blood's level
  /// (docs/decisions.md, stop 68).
  double enhanced_seed_hu = 450.0;
  double contrast_min_volume = 5e-6;
  double contrast_bone_ratio = 0.1;
  /// Contrast-filled blood is looked for above this (HU; 0 for raw volumes: above the bone
  /// threshold only).
  double blood_hu = 200.0;
  /// A thick blob with more than this share of its voxels (rim included) above `cortical_hu`
  /// (raw: `raw_cortical`, 0 = no test) is cancellous bone in its cortical shell, not blood.
  double cortical_hu = 700.0, raw_cortical = 0.0;
  double cortical_fraction = 0.12;
  /// The spine's column about its axis, in each axial slice: half width left-right, and reach
  /// ahead of and behind the axis (m). Ribs are cut from the vertebrae at its edge (the
  /// costotransverse joints lie 25-35 mm from the midline).
  double spine_half_width = 0.026;
  double spine_front = 0.05, spine_back = 0.06;
  /// A piece of the column under `min_rib_volume`, apart from the rest and wholly more than this
  /// ahead of the spine's axis, is a vessel-wall calcification, not spine (m).
  double calcification_ahead = 0.01;
  /// Bone near the posterior midline that fixes the spine's axis: within this of the midline (m).
  double midline_band = 0.025;
  /// ... looked for this far either side of the body's centroid in each slice (m).
  double spine_search = 0.04;
  /// The axis is smoothed by a running median over this far up and down (m).
  double axis_smoothing = 0.03;
  /// The body's axis is the bounding box's centre unless that lies further than this from the
  /// spine's midline left-right (a crop face or an arm pulls it aside): then the midline (m).
  double axis_box_offset = 0.01;
  /// A bone piece lies outside the rib cage (shoulder girdle, arm) when, along the rays from the
  /// body's axis, at least `shoulder_fraction` of it has other bone nearer the axis by more than
  /// `shoulder_gap` (m).
  double shoulder_gap = 0.012;
  double shoulder_fraction = 0.35;
  /// ... or when at least `shoulder_shared_min` of it has other bone first along its rays and,
  /// of that, at least `shoulder_of_shared` lies beyond it by more than the gap.
  double shoulder_shared_min = 0.15, shoulder_of_shared = 0.6;
  /// ... and inside it (not rib) when more than this share has other bone beyond it.
  double inner_fraction = 0.6;
  /// Pieces whose centre is within this fraction of the half body width of the midline, in
  /// front of the spine, are sternum.
  double sternum_lateral = 0.12;
  /// ... and whose centre lies in the front `sternum_wall` of the body's depth at the midline in
  /// its slice (the front wall); behind it, in the mediastinum, a bright piece is a narrow
  /// contrast-filled vessel or a calcification, kept out of the bone's structures.
  double sternum_wall = 0.3;
  /// Ribs, sternum and spine grown from their bright cortex into the marrow and the partial-
  /// volume rim: neighbouring voxels above this (HU; raw volumes: `raw_grow`, 0 = no growth)
  /// within `grow_distance` (m) of the bright bone.
  double grow_hu = 180.0, raw_grow = 0.0;  // above enhanced blood in a venous phase
  double grow_distance = 0.004;
  /// Unenhanced soft tissue stays under `unenhanced_max_hu` (muscle, liver and blood read
  /// 40-80 HU). A scan is unenhanced when under `enhanced_share` of the body lies between it and
  /// the bone threshold more than two voxels from bone (enhanced blood and organs do: 1.5 % of a
  /// venous-phase body, 2.5 % of an arterial one, 0.08 % of a plain scan). In an unenhanced scan
  /// bone grows into voxels above `unenhanced_max_hu` as far as `plain_grow_distance` (m) along
  /// it: hysteresis, keeping a rib's stretch whose partial-volume cortex stays below the bone
  /// threshold in coarse voxels when it joins bone above it.
  double unenhanced_max_hu = 130.0, enhanced_share = 0.005, plain_grow_distance = 0.05;
  /// Rib marrow, below the bone threshold: in each slice, a hole a rib's cross-section encloses
  /// (above `marrow_floor_hu`, at most `marrow_max_area` m², bounded by that rib alone) is the
  /// rib's (HU volumes; 0 = not filled).
  double marrow_floor_hu = -200.0, marrow_max_area = 3e-4;
  /// A rib is slender: a piece over `lump_volume` (m³) whose bounding-box diagonal cubed is
  /// less than `min_rib_elongation` times its volume is a lump of other bone.
  double lump_volume = 2e-6, min_rib_elongation = 25.0;
  /// Bone pieces off the spine smaller than this are fragments (the stubs the spine's column
  /// leaves of a rib's neck), not ribs (m³).
  double min_rib_volume = 1e-6;
  /// ... or shorter than this (bounding-box diagonal, m; a whole rib is 10-30 cm long).
  double min_rib_length = 0.04;
  /// A rib runs around the chest, sloping: a piece off the midline whose head-foot extent is
  /// more than this many times its extent across the axial plane (the larger of left-right and
  /// front-back) is a vessel along the body's axis (an internal mammary artery or vein with
  /// contrast, which reads as bright as a thin rib), not a rib. Ribs measured: head-foot 0.4-1.5
  /// times their axial extent (lidc-idri-0001's labelled ribs and the phantoms').
  double max_rib_axial_ratio = 3.0;
  /// Pieces of one rib are joined (JoinRibPieces) across a break of up to this angle about the
  /// body's axis (rad; the rib dipping below the threshold), or across any stretch where the rib
  /// would run outside the scan (a crop face), when their ends line up: heights within
  /// `rib_join_pitch` of the rib pitch (the height between neighbouring ribs) and radii within
  /// `rib_join_radius` (m).
  /// The pitch is the median height between pieces one above the other at the same angle, of
  /// those under `max_rib_pitch` (m; an adult's ribs lie 2-4 cm apart along the chest wall: a
  /// larger step is between a rib and other bone, a hip or a femur); 25 mm when none is.
  double rib_break_angle = 15.0 * M_PI / 180.0;
  double max_rib_pitch = 0.05;
  double rib_join_pitch = 0.35;
  double rib_join_radius = 0.03;
  /// The rib cage is one stack: each rib spans heights overlapping the next one's (a rib falls
  /// 5-10 cm from its head to its front end, its neighbours lie 2-4 cm apart). Rib-like pieces
  /// more than `rib_stack_gap` (m) above or below the stack of most pieces (then most volume) are
  /// other bone (a femur, the sacrum, lumbar processes in an abdominal scan), not ribs.
  double rib_stack_gap = 0.04;
  /// A rib articulates with its vertebra; a collarbone runs from the manubrium to the shoulder,
  /// far from the spine. A piece of a side at the first rib's height or above (above the second
  /// piece that meets the spine) whose nearest approach to the spine (the spine's centroid in
  /// each of its slices) exceeds the median approach of the side's pieces by more than this (m)
  /// is a collarbone, not rib 1 (KeepCollarbonesOut; 0: off).
  /// Judged only where the side's pieces do meet the spine, their median approach within
  /// `rib_spine_reach` (m: a rib's head lies against its vertebra's body, whose half-width is
  /// 15-20 mm; a scan cropped to the heart or the abdomen shows ribs that do not reach it).
  /// Measured on lidc-idri-0001: its 20 rib pieces come within 21-29 mm of the spine's centroid,
  /// its left collarbone 62 mm; the phantoms' ribs 37-40 mm, all alike.
  /// A collarbone also meets the manubrium at its top and rises toward the shoulder: it is
  /// looked for only with a sternum found, and reaches at least this far below the sternum's top
  /// (m; lidc-idri-0001's left collarbone rises 35 mm above it).
  double collarbone_spine_excess = 0.02, rib_spine_reach = 0.035, collarbone_sternum_margin = 0.01;
  /// Numbering: the top of the rib cage is in view when the scan reaches this far above the
  /// highest rib; the bottom when the spine continues this far below the lowest rib (m).
  double top_margin = 0.015, bottom_spine = 0.03;
  /// A side judged from the rib cage's layer (KeepBoneBeyondTheLayerOutOfRibs): a rib-like piece
  /// is outside the rib cage when at least `layer_judged_share` of its voxels can be judged
  /// against the ribs' surface and over `layer_beyond_share` of those lie beyond it.
  double layer_judged_share = 0.5, layer_beyond_share = 0.67;
};

/// How one side's ribs were numbered.
struct RibNumbering {
  bool numbered = false;
  double confidence = 0.0;  ///< 0..1: how sure the numbers are
  std::string basis;        ///< what the numbers rest on, or why there are none
};

/// Sorts `seg->bone` into `seg->bones` (ribs per side numbered when possible, sternum, spine),
/// `seg->vessels` and `seg->shoulder`; reports what it found in `seg->anatomy`.
void ClassifyBones(const Volume& ct, Segmentation* seg, const AnatomyOptions& options,
                   double min_bone_volume);

/// The shoulder girdle kept out of one side's ribs by the rib cage's layer (LayerChart), for a
/// side whose ribs are judged from the layer (a windowed volume whose ribs read as fragments:
/// there the pieces' own rule, other rib pieces nearer the axis, has too few ribs to go by, and a
/// shoulder blade read alone or merged with rib fragments passes for a rib). A rib-like piece
/// lying mostly further from the body's axis than the ribs' surface by more than the layer's
/// band (`chart.outside`; options `layer_judged_share`, `layer_beyond_share`) goes to
/// `seg->shoulder`, but for its parts within the layer that are ribs by themselves (at least
/// `min_rib_volume` and `min_rib_length`): a first rib merged with its collarbone keeps its
/// bone, as a new rib piece. Voxels behind the spine within twice `spine_half_width` of the
/// midline are not judged: the layer there is the vertebrae's arches. A line in `seg->anatomy`
/// says what moved. Returns the volume moved to the girdle (m³).
double KeepBoneBeyondTheLayerOutOfRibs(const Volume& ct, const LayerChart& chart, int side,
                                       const AnatomyOptions& options, Segmentation* seg);

}  // namespace trocar::patient
