#include "patient/patient_model.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <optional>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/yaml_util.hpp"
#include "patient/anatomy.hpp"
#include "patient/case_file.hpp"
#include "patient/intercostal.hpp"
#include "patient/label_map.hpp"
#include "patient/markups.hpp"
#include "patient/model_cache.hpp"
#include "patient/sanity.hpp"
#include "patient/segmentation.hpp"
#include "patient/surface.hpp"

namespace trocar::patient {

const Structure* PatientModel::Find(const std::string& wanted) const {
  for (const auto& s : structures) {
    if (s.name == wanted) return &s;
  }
  return nullptr;
}

long PatientModel::triangle_count() const {
  long n = 0;
  for (const auto& s : structures) n += static_cast<long>(s.mesh.triangles.size());
  return n;
}

Eigen::Vector3d NearestSurfaceNormal(const TriangleMesh& mesh, const Eigen::Vector3d& p_P) {
  TROCAR_THROW_UNLESS(!mesh.vertices.empty(), mesh.source << ": no vertices for a normal");
  std::size_t best = 0;
  double best_d = HUGE_VAL;
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    const double d = (mesh.vertices[v] - p_P).squaredNorm();
    if (d < best_d) {
      best_d = d;
      best = v;
    }
  }
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  for (const auto& t : mesh.triangles) {
    if (t[0] != int(best) && t[1] != int(best) && t[2] != int(best)) continue;
    n += (mesh.vertices[t[1]] - mesh.vertices[t[0]])
             .cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
  }
  TROCAR_THROW_UNLESS(n.norm() > 0.0, mesh.source << ": vertex " << best << " has no triangles");
  return n.normalized();
}

Eigen::Isometry3d PoseOnTable(const TriangleMesh& skin, double left_side_up, const Table& table) {
  // Supine, head toward +x_W: superior z_P = x_W, posterior y_P = -z_W, left x_P = -y_W; then
  // the left side is raised by rotating about the body axis.
  Eigen::Matrix3d R0;
  R0.col(0) = -Eigen::Vector3d::UnitY();
  R0.col(1) = -Eigen::Vector3d::UnitZ();
  R0.col(2) = Eigen::Vector3d::UnitX();
  const Eigen::Matrix3d R_WP = Eigen::AngleAxisd(-left_side_up, Eigen::Vector3d::UnitX()) * R0;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
  for (const auto& v : skin.vertices) {
    const Eigen::Vector3d w = R_WP * v;
    lo = lo.cwiseMin(w);
    hi = hi.cwiseMax(w);
  }
  Eigen::Isometry3d X_WP = Eigen::Isometry3d::Identity();
  X_WP.linear() = R_WP;
  X_WP.translation() =
      Eigen::Vector3d(-0.5 * (lo.x() + hi.x()), -0.5 * (lo.y() + hi.y()), table.height - lo.z());
  return X_WP;
}

namespace {

Mask LabelMask(const Volume& ct, const std::vector<int>& labels,
               const std::vector<const std::vector<Component>*>& groups) {
  std::vector<std::uint8_t> wanted;
  for (const auto* g : groups) {
    for (const auto& comp : *g) {
      if (comp.label >= int(wanted.size())) wanted.resize(comp.label + 1, 0);
      wanted[comp.label] = 1;
    }
  }
  Mask m;
  m.size = ct.size;
  m.inside.assign(ct.values.size(), 0);
  for (std::size_t n = 0; n < labels.size(); ++n) {
    m.inside[n] = labels[n] > 0 && labels[n] < int(wanted.size()) && wanted[labels[n]];
  }
  return m;
}


}  // namespace

// A roll is corrected from 5 degrees (the sorting holds to about that: a phantom rolled 5 degrees
// numbers both sides, 8 degrees loses one) up to 30 (beyond it the header is more likely wrong
// than the patient rolled: the orientation check judges it), on a cross-section clearly wider
// than deep (a chest 1.3-1.6, the phantoms 2.0; a round one gives no direction).
constexpr double kRollMinDegrees = 5.0, kRollMaxDegrees = 30.0, kRollMinAspect = 1.25;
// A grid whose axes are turned from the patient's by more than this is resampled along them (the
// sorting reads the grid's rows; a phantom on a grid turned 12 degrees lost 10 of its 12 left
// ribs). Under it the header's numbers are rounding, not a reconstruction's choice.
constexpr double kObliqueGridDegrees = 1.0;

namespace {

// One import of a case's CT into its model, as named stages over the state they share: the
// phantom generated when outdated, the cache tried (before and after decoding the CT), the CT
// loaded and its units settled, body and bone segmented, a roll or an oblique grid turned
// upright, the label map, the rib cage's layer, the heart, the checks, the surfaces, what is
// missing, the targets, the port candidates (then off the cut faces), the model carried back to
// the CT's frame, the cache written. Run() runs them in that order; each stage's time is
// reported.
struct CtImport {
  using Clock = std::chrono::steady_clock;

  CtImport(const std::string& case_dir, const CaseSpec& c, const ImportOptions& options)
      : case_dir(case_dir),
        c(c),
        options(options),
        cache_dir(JoinPath(case_dir, "cache")),
        model_bin(JoinPath(cache_dir, "model.bin")) {}

  ImportedPatient Run() {
    GenerateIfOutdated();
    ImportedPatient cached;
    if (FromCacheBeforeDecoding(&cached)) return cached;
    Stage("load CT", [&] { ct = LoadVolume(c.ct); });
    key = CacheKey(c, ct.files);
    if (cache_exists) {
      ImportedPatient loaded;
      if (FromCache(key, &loaded)) return loaded;
    }
    SettleUnits();
    Stage("segment body and bone", [&] { seg = Segment(ct, c.seg); });
    Stage("roll", [&] { TurnUpright(); });
    if (have_labels) Stage("label map", [&] { FromLabelMap(); });
    if (!ct.hounsfield && !have_labels) Stage("rib cage layer", [&] { ChartRibCageLayer(); });
    m.body_min_P = seg.body_min_P;
    m.body_max_P = seg.body_max_P;
    Stage("heart", [&] { FindHeart(); });
    Stage("checks", [&] { RunChecks(); });
    if (!have_heart) {
      report.warnings.push_back(
          "no heart in the model (heart.contrast is false and there is no heart "
          "mask or label): plans will not avoid it");
    }
    if (!heart_note.empty()) report.warnings.push_back(heart_note);
    voxel = std::abs(ct.index_to_P.determinant());
    Stage("surfaces", [&] { Surfaces(); });
    SayWhatIsMissing();
    Stage("targets", [&] { Targets(); });
    Stage("port candidates", [&] { PortCandidates(); });
    KeepPortsOffCutFaces();
    if (upright) BackToTheCtFrame();
    m.X_WP = PoseOnTable(m.Find("skin")->mesh, m.left_side_up, m.table);
    if (options.write_cache) {
      // A case folder one cannot write to (a read-only checkout) still gives its model.
      Stage("write cache", [&] {
        try {
          WriteCacheFiles(m, report, cache_dir, key, ct.files);
        } catch (const Error& e) {
          report.cache_error = e.what();
        }
      });
    }
    // Said for this import only (the cache just written is sound).
    if (!cache_damage.empty()) report.warnings.push_back(cache_damage);
    report.timings = timings;
    ImportedPatient built;
    built.model = std::make_shared<const PatientModel>(std::move(m));
    built.report = std::move(report);
    return built;
  }

  // Runs one stage, timed and shown as progress. The warnings said so far (the report's, once it
  // exists): a stage that then fails carries them in its error, so that a warning that explains
  // the failure (a header normalised, a mask resampled) is not lost with the model that would
  // have reported it.
  void Stage(const std::string& name, const std::function<void()>& f) {
    const auto t0 = Clock::now();
    if (options.progress) options.progress(name);
    try {
      f();
    } catch (const Error& e) {
      if (warnings_told || said == nullptr || said->empty()) throw;
      warnings_told = true;
      std::string message = e.what();
      message += "\n  (warnings before this error, while importing:";
      for (const auto& w : *said) message += "\n   - " + w;
      message += ")";
      throw Error(message);
    }
    timings.emplace_back(name, std::chrono::duration<double>(Clock::now() - t0).count());
  }

  // A phantom case's CT is generated on first use, and again when an older generator made it
  // (the anatomy it lays out has changed since).
  void GenerateIfOutdated() {
    const bool outdated = c.has_phantom && std::filesystem::path(c.ct).filename() == "ct.nrrd" &&
                          IsRegularFile(c.ct) && !PhantomCaseIsCurrent(case_dir);
    if (c.has_phantom && (outdated || !std::filesystem::exists(c.ct))) {
      Stage("generate phantom", [&] {
        WritePhantomCase(GeneratePhantom(c.phantom), case_dir, CtFormat::kNrrdLps,
                         /*write_patient_yaml=*/false);
      });
    }
  }

  // A cached model with the report of its build (checks, warnings) and of this load.
  bool FromCache(std::uint64_t cache_key, ImportedPatient* cached) {
    const auto t0 = Clock::now();
    std::string damage;
    PatientModel model;
    if (!DeserializeModel(ReadBinaryFile(model_bin), cache_key, &model, &cached->report, &damage)) {
      if (!damage.empty()) cache_damage = model_bin + ": " + damage + "; rebuilt from the CT";
      return false;
    }
    model.case_dir = case_dir;
    cached->model = std::make_shared<const PatientModel>(std::move(model));
    cached->report.from_cache = true;
    cached->report.timings = timings;
    cached->report.timings.emplace_back("load cache", std::chrono::duration<double>(Clock::now() - t0).count());
    return true;
  }

  // Keyed by the CT files the last build read, without decoding the CT (a clinical CT takes a
  // second to decode; the whole cached load must take less).
  bool FromCacheBeforeDecoding(ImportedPatient* cached) {
    cache_exists = options.use_cache && IsRegularFile(model_bin);
    if (!cache_exists) return false;
    const std::vector<std::string> last_ct_files = ReadCtFiles(cache_dir);
    if (last_ct_files.empty()) return false;
    std::uint64_t last_key = 0;
    Stage("key inputs", [&] { last_key = CacheKey(c, last_ct_files); });
    return FromCache(last_key, cached);
  }

  // The CT's units: as the case file says, CT numbers stored without their intercept converted,
  // a raw volume's range checked against the default thresholds; the model's first fields.
  void SettleUnits() {
    if (c.units == 1) ct.hounsfield = true;
    if (c.units == 2) ct.hounsfield = false;
    said = &report.warnings;
    m.name = c.name;
    m.case_dir = case_dir;
    report.warnings.insert(report.warnings.end(), ct.warnings.begin(), ct.warnings.end());
    // CT numbers stored without their rescale intercept are converted and said (units: raw keeps
    // them as they are).
    double soft_tissue = 0.0;
    if (c.units != 2 && LooksLikeCtNumbersWithoutIntercept(ct, &soft_tissue)) {
      for (float& x : ct.values) x -= 1024.0f;
      ct.hounsfield = true;
      std::ostringstream w;
      w << c.ct << ": no value below 0, air near 0 and soft tissue near "
        << std::lround(soft_tissue)
        << ": read as CT numbers stored without their rescale intercept, converted to Hounsfield "
           "units (value - 1024); set units: raw in "
        << c.file << " if they are not";
      report.warnings.push_back(w.str());
    }
    // The default raw thresholds are an 8-bit window's: a raw volume beyond that range needs its
    // own.
    if (!ct.hounsfield && !c.thresholds_given && !ct.values.empty()) {
      const auto [lo, hi] = std::minmax_element(ct.values.begin(), ct.values.end());
      TROCAR_THROW_UNLESS(*hi <= 255.5f,
                          c.ct << ": read as a windowed volume ("
                               << (c.units == 2 ? "units: raw" : "no value at or below -500 HU")
                               << ") but not an 8-bit window (values " << *lo << " to " << *hi
                               << "): the default thresholds for windowed volumes (body "
                               << c.seg.raw_body << ", bone " << c.seg.raw_bone
                               << ") do not fit it; give thresholds: {body: ..., "
                               << "bone: ...} in the CT's own units in " << c.file
                               << ", or units: hounsfield if its values are HU");
    }
    if (ct.hounsfield && c.intercostal.layer_floor > 0.0) {
      report.warnings.push_back(
          "thresholds.rib is for windowed volumes (units: raw); this CT is in Hounsfield units, "
          "its "
          "spaces are found between its ribs: not used");
    }
    m.ct_source = c.ct;
    m.table = c.table;
    m.left_side_up = c.left_side_up;
  }

  // A roll or an oblique grid: the CT resampled onto a grid along an upright frame D.
  void TurnUpright() {
    const BodyRoll roll = MeasureBodyRoll(ct, seg.body);
    faces_P = FindCutFaces(ct, seg.body);
    bool cut_around = false;  // a crop face on the sides: the cross-section is not the body's
    for (const CutFace& f : faces_P)
      cut_around = cut_around || (f.name != "superior" && f.name != "inferior");
    const double degrees = roll.angle * 180.0 / M_PI;
    const bool rolled = !cut_around && roll.aspect >= kRollMinAspect &&
                        std::abs(degrees) >= kRollMinDegrees &&
                        std::abs(degrees) <= kRollMaxDegrees;
    // A grid turned from the patient's axes (an oblique header): the patient may lie straight in
    // the patient frame while the grid's rows run across him. D is then the patient frame itself.
    const double oblique = GridObliquity(ct) * 180.0 / M_PI;
    if (!rolled && oblique <= kObliqueGridDegrees) return;
    if (rolled) {
      X_DP = Eigen::Translation3d(roll.centre_P) *
             Eigen::AngleAxisd(-roll.angle, Eigen::Vector3d::UnitZ()) *
             Eigen::Translation3d(-roll.centre_P);
    }
    grid_P.size = ct.size;
    grid_P.index_to_P = ct.index_to_P;
    grid_P.origin_P = ct.origin_P;
    grid_P.source = ct.source;
    // The scan's values as they are (nearest voxel), on a grid along D's axes (the sorting also
    // reads the grid's rows), over the body and a margin (a whole turned grid is up to 40 %
    // larger).
    ct = ResampleTurned(ct, X_DP, *std::min_element(ct.values.begin(), ct.values.end()), &seg.body);
    seg = Segment(ct, c.seg);
    upright = true;
    std::ostringstream s;
    s << std::fixed << std::setprecision(1);
    if (oblique > kObliqueGridDegrees) {
      s << "CT: its grid is turned " << oblique
        << " degrees from the patient's axes (an oblique header or a gantry tilt): resampled, "
           "nearest voxel, onto a grid along "
        << (rolled ? "the upright frame below" : "them") << "; the model is in the CT's frame";
      report.checks.push_back(s.str());
      s.str("");
    }
    if (rolled) {
      s << "body: the patient lies rolled " << std::abs(degrees) << " degrees about the long axis, "
        << (degrees > 0 ? "right" : "left") << " side up (the body's cross-section, "
        << std::setprecision(2) << roll.aspect
        << " times as wide as deep, is turned from the scan's left-right axis): sorted in a frame "
           "turned upright about the body's centroid; the model is in the CT's frame";
      report.checks.push_back(s.str());
    }
  }

  // Bones, heart and vessels from the label map; the body (skin) stays the CT's own.
  void FromLabelMap() {
    LabelMap map = LoadLabelMap(c.labels, c.label_names);
    MoveVolumeFrame(X_DP, &map.volume);
    labelled = AnatomyFromLabels(map, ct);
    seg.bones = labelled.bones;
    CheckLabelsAgainstCt();
  }

  // A label map whose ribs do not lie on this CT's ribs (another patient's, or shifted) is
  // refused with the overlap measured, never used silently (issue #42, bad input).
  void CheckLabelsAgainstCt() {
    const LabelAgreement a = MeasureLabelAgreement(ct, seg.bones, seg.bone_threshold);
    if (a.rib_voxels == 0) return;
    std::ostringstream s;
    s << "label map: " << std::lround(100 * a.here) << " % of its " << a.rib_voxels
      << " rib voxels are bone-bright on the CT";
    if (a.best > a.here) {
      const Eigen::Vector3d mm = a.best_move_P * 1e3;
      s << " (" << std::lround(100 * a.best) << " % moved " << std::lround(mm.x()) << ", "
        << std::lround(mm.y()) << ", " << std::lround(mm.z()) << " mm)";
    } else {
      s << " (fewer moved 5-30 mm along any axis)";
    }
    // Twice as many moved by 5 to 30 mm: the map is shifted, or another patient's. A map of this
    // CT lies best where it is (lidc-idri-0001: 20 % unmoved, less moved; its map moved 6 mm
    // reads 9 % against 20 %, 12 mm 1 % against 16 %, 30 mm toward the head 5 % against 20 %). In
    // Hounsfield units, a map whose ribs lie on almost no bone anywhere near is refused too (a
    // windowed scan's ribs are mostly below its bone threshold: not judged so).
    const bool shifted = a.here < 0.5 * a.best;
    const bool nowhere = ct.hounsfield && a.best < 0.03;
    TROCAR_THROW_UNLESS(
        !shifted && !nowhere,
        c.labels << ": its ribs do not lie on this CT's ribs: " << s.str().substr(11)
                 << (nowhere ? "; hardly any labelled rib voxel is bone" : "")
                 << ": a label map of another scan, or its header's origin is off; "
                    "give this CT's own label map");
    if (a.here < 0.8 * a.best)
      report.warnings.push_back(s.str() +
                                ": the map may be shifted against the CT; check its origin");
    report.checks.push_back(s.str());
  }

  // A side of a windowed volume (raw units, no label map) whose ribs are not numbered is judged
  // from the chart of the rib cage's layer: its ribs' cross-sections are mostly below the bone
  // threshold, and the components are fragments. The chart keeps the shoulder girdle out of its
  // ribs, and gives its intercostal spaces (port candidates, below).
  void ChartRibCageLayer() {
    // Both unnumbered sides in one chart (one distance transform for the wall's depth).
    IntercostalOptions both = c.intercostal;
    both.left = !seg.numbering_left.numbered;
    both.right = !seg.numbering_right.numbered;
    if (!both.left && !both.right) return;
    LayerChart chart;
    std::vector<IntercostalSpace> found;
    try {
      found = FindIntercostalSpacesInLayer(ct, seg, both, &chart, &layer_reach);
    } catch (const Error& e) {
      // Needed for the ports (not annotated, and asked of an unnumbered side): the error
      // stands. Needed for the girdle only: the import goes on with the pieces' own rule, and
      // says so.
      if (c.port_markups.empty() &&
          ((c.intercostal.left && both.left) || (c.intercostal.right && both.right)))
        throw;
      report.warnings.push_back(std::string("bones: the rib cage's layer could not be charted (") +
                                e.what() +
                                "): the shoulder girdle is judged by the bone pieces alone");
      return;
    }
    layer_floor = chart.floor;
    for (int side : {+1, -1}) {
      if (!(side > 0 ? both.left : both.right)) continue;
      if (c.seg.shape_anatomy)
        KeepBoneBeyondTheLayerOutOfRibs(ct, chart, side, c.seg.anatomy, &seg);
      layer_side[side > 0 ? 0 : 1] = true;
    }
    for (auto& space : found) layer_spaces[space.side > 0 ? 0 : 1].push_back(std::move(space));
  }

  // The heart: from a mask, the label map, the contrast-filled blood pool, or approximated from
  // the mediastinum (and said); a heart of more than 3 litres is refused.
  void FindHeart() {
    if (!c.heart_mask.empty()) {
      Volume mask = LoadVolume(c.heart_mask);
      MoveVolumeFrame(X_DP, &mask);
      heart = ResampleMask(mask, ct, c.heart_mask_threshold);
      TROCAR_THROW_UNLESS(heart.count() > 0, c.heart_mask << ": the heart mask is empty on the CT");
      have_heart = true;
    } else if (have_labels && labelled.heart.count() > 0) {
      heart = labelled.heart;
      have_heart = true;
    } else if (c.heart_contrast == true) {
      heart = SegmentHeartFromContrast(ct, seg, c.heart);
      have_heart = true;
    } else if (!c.heart_contrast.has_value()) {
      // Contrast detected, not declared: without it the heart is approximated, and says so.
      if (std::optional<Mask> pool = TrySegmentHeartFromContrast(ct, seg, c.heart)) {
        heart = std::move(*pool);
      } else {
        heart = ApproximateHeartFromMediastinum(ct, seg, c.heart);
        std::ostringstream w;
        w << "heart: no contrast detected; the heart is APPROXIMATED from the mediastinum (soft "
             "tissue between the lungs, in front of them: "
          << std::lround(heart.count() * std::abs(ct.index_to_P.determinant()) * 1e6)
          << " ml, the great vessels' roots included). Plans avoid this region; give "
             "heart.mask or a label map for the heart itself";
        heart_note = w.str();
      }
      have_heart = true;
    }
    if (have_heart) {
      // An adult heart holds 0.3-1.2 litres (an enlarged one up to ~2): far more is a mask or
      // thresholds that took in the whole mediastinum or body, never a heart to plan around.
      const double litres = heart.count() * std::abs(ct.index_to_P.determinant()) * 1e3;
      TROCAR_THROW_UNLESS(litres <= 3.0,
                          c.file << ": the heart came out as " << litres << " litres (at most ~2 "
                                 << "in a real chest) from "
                                 << (!c.heart_mask.empty() ? "heart.mask " + c.heart_mask
                                     : have_labels        ? "the label map " + c.labels
                                                          : std::string("the thresholds heart.blood and heart.soft"))
                                 << ": check them");
    }
  }

  // Orientation from anatomy, what the bone sorting found, the scan's cut faces.
  void RunChecks() {
    // Orientation from anatomy: a flipped or mirrored header is an error (or, with
    // orientation: {check: false}, a warning), never a silent import.
    const OrientationCheck o = CheckOrientation(ct, seg, have_heart ? &heart : nullptr);
    for (const auto& f : o.findings) report.checks.push_back("orientation: " + f);
    if (o.flipped()) {
      std::ostringstream what;
      what << c.ct << ": the anatomy disagrees with the header's orientation:";
      for (const auto& f : o.findings) what << "\n  " << f;
      what << "\n(fix the header, e.g. re-export the CT from the scanner's DICOM; or, for a "
              "patient whose anatomy is mirrored, set orientation: {check: false} in "
           << c.file << ")";
      TROCAR_THROW_UNLESS(!c.check_orientation, what.str());
      report.warnings.push_back("orientation: the anatomy disagrees with the header (not checked, "
                           "orientation.check is false)");
    }
    if (o.heart_misplaced) {
      // A heart the user gave is checked, not second-guessed; a found one is probably none.
      const bool given = !c.heart_mask.empty() || (have_labels && labelled.heart.count() > 0);
      const std::string from = !c.heart_mask.empty() ? "heart.mask " + c.heart_mask
                               : given               ? "the label map " + c.labels
                               : !heart_note.empty() ? std::string("the mediastinum approximation")
                                                     : std::string("a contrast-filled blood pool");
      report.warnings.push_back(
          "heart: the heart from " + from +
          " lies behind the lungs' centre, the spine at the back" +
          (given ? std::string(": check that it belongs to this CT and lies as its header says; it "
                               "did not judge the header")
                 : std::string(": it is probably no heart (in an abdominal scan, contrast in a "
                               "kidney or the bowel); plans avoid it as the heart. Give heart.mask "
                               "or a label map, or heart: {contrast: false} for a scan without the "
                               "heart")));
    }
    // What the bone sorting found, and on what the ribs' numbers rest (or why there are none).
    if (!seg.body_table.empty()) report.checks.push_back("body: " + seg.body_table);
    if (!seg.body_fill.empty()) report.checks.push_back("body: " + seg.body_fill);
    for (const auto& a : seg.anatomy) report.checks.push_back("bones: " + a);
    if (!have_labels) {
      for (int side : {+1, -1}) {
        const RibNumbering& n = side > 0 ? seg.numbering_left : seg.numbering_right;
        const auto& ribs = side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
        std::ostringstream line;
        line << (side > 0 ? "left" : "right") << " ribs: " << ribs.size() << "; ";
        if (n.numbered) {
          line << "numbered, confidence " << std::fixed << std::setprecision(2) << n.confidence << ": ";
        }
        line << (n.basis.empty() ? std::string("not numbered (bones: place)") : n.basis);
        report.checks.push_back(line.str());
      }
    }
    cut_faces = upright ? faces_P : FindCutFaces(ct, seg.body);
    for (const CutFace& f : cut_faces) {
      m.cut_faces.push_back(f.name);
      if (f.name != "superior" && f.name != "inferior") {
        std::ostringstream s;
        s << "the body is cut by the scan's " << f.name << " face (" << std::setprecision(2) << 100 * f.body_fraction
          << "% of it): the skin there is a crop face; no port candidate within "
          << PatientModel::kCutFaceMargin * 1e3 << " mm of it";
        report.warnings.push_back(s.str());
      }
    }
    if (!m.cut_faces.empty()) {
      std::string names;
      for (const auto& n : m.cut_faces) names += (names.empty() ? "" : ", ") + n;
      report.checks.push_back("cut faces: " + names);
    }
  }

  // The structures' surfaces.
  void Surfaces() {
    // Each structure's surface on its own (VTK pipelines of their own), at most two at a time
    // (each made mask is a whole-volume array), the ribs (the largest contour) first. The model
    // keeps the order below whatever finished first.
    // A job surfaces a mask the import holds (`given`) or one it makes from the bone labels.
    struct Job {
      std::string name;
      const Mask* given;
      std::function<Mask()> make;
      int budget;
    };
    std::vector<Job> jobs = {
        {"ribs", nullptr,
         [&] { return LabelMask(ct, seg.bones.labels, {&seg.bones.ribs_left, &seg.bones.ribs_right}); },
         c.budgets.ribs},
        {"skin", &seg.body, nullptr, c.budgets.skin},
        {"sternum", nullptr, [&] { return LabelMask(ct, seg.bones.labels, {&seg.bones.sternum}); }, c.budgets.sternum},
        {"spine", nullptr, [&] { return LabelMask(ct, seg.bones.labels, {&seg.bones.spine}); }, c.budgets.spine},
    };
    if (have_heart) jobs.push_back({"heart", &heart, nullptr, c.budgets.heart});
    if (have_labels) jobs.push_back({"vessels", &labelled.vessels, nullptr, c.budgets.vessels});
    std::vector<std::optional<Structure>> made(jobs.size());
    std::vector<std::exception_ptr> failed(jobs.size());
#pragma omp parallel for schedule(dynamic, 1) num_threads(2)
    for (int j = 0; j < static_cast<int>(jobs.size()); ++j) {
      try {
        Mask owned;
        if (jobs[j].given == nullptr) owned = jobs[j].make();
        const Mask& mask = jobs[j].given != nullptr ? *jobs[j].given : owned;
        if (mask.count() == 0) continue;
        SurfaceOptions o = c.surface;
        o.max_triangles = jobs[j].budget;
        o.max_working_spacing = MaxWorkingSpacing(jobs[j].name);
        SurfaceReport surface_report;
        Structure s;
        s.name = jobs[j].name;
        s.mesh = ExtractSurface(ct, mask, jobs[j].name, o, &surface_report);
        s.volume = mask.count() * voxel;
        s.contoured_triangles = surface_report.contoured_triangles;
        made[j] = std::move(s);
      } catch (...) {
        failed[j] = std::current_exception();
      }
    }
    for (const auto& e : failed) {
      if (e) std::rethrow_exception(e);
    }
    for (const char* name : {"skin", "ribs", "sternum", "spine", "heart", "vessels"}) {
      for (auto& s : made) {
        if (s && s->name == name) m.structures.push_back(std::move(*s));
      }
    }
  }

  // Nothing missing silently (issue #42 item 3): a structure the scan covers that the model
  // lacks is a warning naming it and why it matters. The ribs found on both sides mean the scan
  // covers the front of the chest between them, where the sternum is; ribs on one side only
  // (the other side in the scan: not a cut face) mean the other side's were not found.
  void SayWhatIsMissing() {
    const bool left = !seg.bones.ribs_left.empty(), right = !seg.bones.ribs_right.empty();
    if (left && right && m.Find("sternum") == nullptr) {
      report.warnings.push_back(
          "no sternum found, though the ribs of both sides are (the scan covers the front of the "
          "chest): the midline, the parasternal lines and the LIMA's course are placed without "
          "it; give a label map (labels:) with the sternum, or check the bone threshold");
    }
    for (const int side : {+1, -1}) {
      const bool here = side > 0 ? left : right, there = side > 0 ? right : left;
      const char* name = side > 0 ? "left" : "right";
      if (here || !there) continue;
      if (std::find(m.cut_faces.begin(), m.cut_faces.end(), name) != m.cut_faces.end()) continue;
      report.warnings.push_back(std::string("no ribs found on the ") + name +
                                " side, though the scan covers it and the other side's are "
                                "found: its intercostal spaces (ports) are missing");
    }
  }

  // The targets from their markups, inside the scanned box, with their approach normals.
  void Targets() {
    for (const auto& spec : c.targets) {
      const auto markups = LoadMarkups(spec.markups);
      Target t;
      t.name = spec.name;
      for (const auto& mk : markups) {
        for (const auto& p : mk.points) t.points.push_back(X_DP * p);
        for (const auto& n : mk.normals) t.normals.push_back(X_DP.linear() * n);
      }
      TROCAR_THROW_UNLESS(!t.points.empty(), spec.markups << ": target '" << spec.name << "' has no points");
      // Every target point inside the scanned box: beyond it the model knows nothing.
      {
        const Eigen::Matrix3d to_index = ct.index_to_P.inverse();
        int outside = 0;
        Eigen::Vector3d first = Eigen::Vector3d::Zero();
        for (const auto& p : t.points) {
          const Eigen::Vector3d ijk = to_index * (p - ct.origin_P);
          const bool in = (ijk.array() >= -0.5).all() && (ijk.array() <= ct.size.cast<double>().array() - 0.5).all();
          if (!in && outside++ == 0) first = p;
        }
        TROCAR_THROW_UNLESS(outside == 0, spec.markups << ": target '" << spec.name << "': " << outside << " of "
                                                       << t.points.size() << " points lie outside the CT "
                                                       << c.ct << " (the first at " << (first * 1e3).transpose()
                                                       << " mm, LPS); is this the same patient and frame?");
      }
      const bool from_file = spec.normals != "surface" && t.normals.size() == t.points.size();
      TROCAR_THROW_UNLESS(from_file || spec.normals != "file",
                          c.file << ": target '" << spec.name << "': normals: file, but "
                                 << spec.markups << " has no orientation for every point");
      if (from_file) {
        t.normals_from = "file";
      } else {
        const Structure* surface = m.Find(spec.surface);
        TROCAR_THROW_UNLESS(surface != nullptr,
                            c.file << ": target '" << spec.name << "': surface '" << spec.surface
                                   << "' is not a structure of this model (skin, ribs, sternum, "
                                      "spine, heart)");
        t.normals.clear();
        for (const auto& p : t.points) {
          const Eigen::Vector3d n = NearestSurfaceNormal(surface->mesh, p);
          t.normals.push_back(spec.inward ? -n : n);
        }
        t.normals_from = "surface:" + spec.surface + (spec.inward ? " (inward)" : "");
      }
      m.targets.push_back(std::move(t));
    }
  }

  // The port candidates: annotated curves, or the intercostal spaces found, named from the ribs'
  // numbers.
  void PortCandidates() {
    for (const auto& file : c.port_markups) {
      for (const auto& mk : LoadMarkups(file)) {
        Curve skin;
        for (const auto& p : mk.points) skin.push_back(X_DP * p);
        m.port_candidates.push_back({mk.name, skin, "markups:" + file});
      }
    }
    if (m.port_candidates.empty()) {
      // Named from the ribs' anatomical numbers (a label map's, or the numbering of
      // ClassifyBones with its confidence); spaces between ribs that are not numbered are
      // called gap-L1, gap-L2, ... from the top: an order, never an anatomical name. Sides
      // judged from the rib cage's layer have their spaces from it (found above); numbered ribs
      // keep their named spaces.
      int unnamed[2] = {0, 0};
      std::vector<IntercostalSpace> spaces;
      std::vector<WallReach> reach;
      bool any_layer = false;
      for (int side : {+1, -1}) {
        if (!(side > 0 ? c.intercostal.left : c.intercostal.right)) continue;
        if (layer_side[side > 0 ? 0 : 1]) {
          if (!any_layer) {
            std::ostringstream s;
            s << "intercostal spaces: from the rib cage's layer (a windowed volume whose ribs are "
                 "not numbered: ribs at or above "
              << std::fixed << std::setprecision(1) << layer_floor << " within "
              << std::setprecision(0) << c.intercostal.layer_depth * 1e3 << " mm of the skin)";
            report.checks.push_back(s.str());
            any_layer = true;
          }
          for (auto& space : layer_spaces[side > 0 ? 0 : 1]) spaces.push_back(std::move(space));
          for (const WallReach& r : layer_reach) {
            if (r.side == side) reach.push_back(r);
          }
          continue;
        }
        IntercostalOptions one = c.intercostal;
        one.left = side > 0;
        one.right = side < 0;
        for (auto& space : FindIntercostalSpaces(ct, seg, one, &reach))
          spaces.push_back(std::move(space));
      }
      // A chest wall thicker than the usual bound, or rays that ran into an arm: say so.
      for (const WallReach& r : reach) {
        rays_kept += r.kept;
        rays_under_arm += r.dropped;
        if (r.dropped == 0 && r.limit <= c.intercostal.max_wall_depth) continue;
        std::ostringstream s;
        s << "ports: " << (r.side > 0 ? "left" : "right") << " chest wall "
          << std::lround(r.typical * 1e3) << " mm from the ribs to the skin (lower quartile of "
          << r.kept + r.dropped << " rays over the spaces)";
        if (r.limit > c.intercostal.max_wall_depth)
          s << ", thicker than " << std::lround(c.intercostal.max_wall_depth * 1e3)
            << " mm: points up to " << std::lround(r.limit * 1e3) << " mm deep kept";
        if (r.dropped > 0)
          s << "; " << r.dropped << " rays stay in the body further than "
            << std::lround(r.limit * 1e3)
            << " mm (an arm against the chest, a breast: too deep for a port): no port there";
        report.checks.push_back(s.str());
      }
      for (const auto& space : spaces) {
        const auto& ribs = space.side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
        const RibNumbering& numbering = space.side > 0 ? seg.numbering_left : seg.numbering_right;
        const std::string side = space.side > 0 ? "L" : "R";
        const int upper = space.upper_rib >= 0 ? ribs[space.upper_rib].number : 0;
        const int lower = space.lower_rib >= 0 ? ribs[space.lower_rib].number : 0;
        PortCandidate candidate;
        candidate.skin = space.skin;
        if (upper > 0 && lower == upper + 1) {
          // The space below rib N is the Nth.
          candidate.name = "ICS-" + side + std::to_string(upper);
          std::ostringstream source;
          source << "intercostal:";
          if (have_labels) {
            source << "labels";
          } else {
            source << "numbered (confidence " << std::fixed << std::setprecision(2) << numbering.confidence << ": "
                   << numbering.basis << ")";
          }
          candidate.source = source.str();
        } else if (upper > 0 || lower > 0) {
          continue;  // numbered ribs not consecutive (one not labelled or not found): no name fits
        } else if (c.intercostal.count_from > 0) {
          // Counted in order from the top as the case file says (the user's count, not ours).
          const int n = c.intercostal.count_from + unnamed[space.side > 0 ? 0 : 1]++;
          candidate.name = "ICS-" + side + std::to_string(n);
          candidate.source = "intercostal (ribs not numbered: " +
                             (numbering.basis.empty() ? std::string("no numbering") : numbering.basis) +
                             "; counted in order from ICS-" + side +
                             std::to_string(c.intercostal.count_from) +
                             " as the case file states, intercostal.count_from)";
        } else {
          candidate.name = "gap-" + side + std::to_string(++unnamed[space.side > 0 ? 0 : 1]);
          candidate.source =
              space.upper_rib < 0
                  ? std::string("intercostal (rib cage layer of a windowed volume: not numbered)")
                  : "intercostal (ribs not numbered: " +
                        (numbering.basis.empty() ? std::string("no numbering") : numbering.basis) +
                        ")";
        }
        auto same = std::find_if(m.port_candidates.begin(), m.port_candidates.end(),
                                 [&](const PortCandidate& p) { return p.name == candidate.name; });
        if (same == m.port_candidates.end()) {
          m.port_candidates.push_back(std::move(candidate));
        } else if (candidate.skin.size() > same->skin.size()) {
          *same = std::move(candidate);  // two pieces of one rib pair: the longer run
        }
      }
    }
  }

  // No port on a crop face: points within the margin of a face the body is cut by go.
  void KeepPortsOffCutFaces() {
    const auto& faces = cut_faces;
    std::vector<PortCandidate> kept;
    int dropped_points = 0, dropped_curves = 0;
    for (auto& cand : m.port_candidates) {
      Curve inside;
      for (const auto& p : cand.skin) {
        bool near = false;
        for (const auto& f : faces) {
          near = near || (upright ? DistanceToCutFace(grid_P, f, X_DP.inverse() * p)
                                  : DistanceToCutFace(ct, f, p)) < PatientModel::kCutFaceMargin;
        }
        if (near) {
          ++dropped_points;
        } else {
          inside.push_back(p);
        }
      }
      if (inside.size() >= 2) {
        cand.skin = std::move(inside);
        kept.push_back(std::move(cand));
      } else {
        ++dropped_curves;
      }
    }
    if (dropped_points > 0) {
      std::ostringstream w;
      w << "port candidates: " << dropped_points << " points";
      if (dropped_curves > 0) w << " (" << dropped_curves << " whole curves)";
      w << " lay within " << PatientModel::kCutFaceMargin * 1e3 << " mm of the scan's cut faces and were left out";
      report.warnings.push_back(w.str());
    }
    m.port_candidates = std::move(kept);
    if (m.port_candidates.empty()) {
      std::ostringstream w;
      w << "no port candidates: ";
      if (dropped_curves > 0) {
        w << "the " << (c.port_markups.empty() ? "intercostal spaces found" : "annotated curves")
          << " all lie at the scan's cut faces";
      } else if (!c.port_markups.empty()) {
        w << "the annotated files hold no curve";
      } else {
        const int left = static_cast<int>(seg.bones.ribs_left.size()), right = static_cast<int>(seg.bones.ribs_right.size());
        w << "no intercostal space was found (ribs found: " << left << " left, " << right
          << " right; sides asked: " << (c.intercostal.left ? "left" : "") << (c.intercostal.left && c.intercostal.right ? ", " : "")
          << (c.intercostal.right ? "right" : "") << ")";
        if (rays_kept == 0 && rays_under_arm > 0)
          w << ": between the ribs, all " << rays_under_arm
            << " rays out to the skin stay in the body further than the chest wall's reach (an "
               "arm against the chest, a breast)";
      }
      w << "; annotate them (port_candidates: in patient.yaml) or give a label map (labels:)";
      report.warnings.push_back(w.str());
    }
  }

  // The model back in the CT's frame; the body's box from its voxels' centres there.
  void BackToTheCtFrame() {
    const Eigen::Isometry3d X_PD = X_DP.inverse();
    for (auto& structure : m.structures) {
      for (auto& v : structure.mesh.vertices) v = X_PD * v;
    }
    for (auto& t : m.targets) {
      for (auto& p : t.points) p = X_PD * p;
      for (auto& n : t.normals) n = X_PD.linear() * n;
    }
    for (auto& candidate : m.port_candidates) {
      for (auto& p : candidate.skin) p = X_PD * p;
    }
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          if (!seg.body.inside[ct.Index(i, j, k)]) continue;
          const Eigen::Vector3d p = X_PD * ct.PatientPoint(i, j, k);
          lo = lo.cwiseMin(p);
          hi = hi.cwiseMax(p);
        }
      }
    }
    m.body_min_P = lo;
    m.body_max_P = hi;
  }

  const std::string& case_dir;
  const CaseSpec& c;
  const ImportOptions& options;
  const std::string cache_dir, model_bin;
  std::vector<std::pair<std::string, double>> timings;  // per stage run, s
  const std::vector<std::string>* said = nullptr;       // the warnings so far (the report's)
  bool warnings_told = false;
  bool cache_exists = false;
  std::string cache_damage;  // why a cache that was there could not be trusted
  std::uint64_t key = 0;     // of the inputs, for the cache
  Volume ct;
  PatientModel m;
  ImportReport report;
  Segmentation seg;
  // A patient lying rolled about the long axis (a wedge under one side, a scoliotic chest): the
  // sorting by shape reads left-right and front-back along the scan's axes, and at 8-15 degrees
  // lost ribs and their numbers. The body's cross-section (wider than deep) gives the roll; the
  // import then works in a frame D turned upright about the body's centroid (the CT resampled
  // onto a grid along D's axes), with every input given in P carried into D and the model
  // carried back into P at the end.
  Eigen::Isometry3d X_DP = Eigen::Isometry3d::Identity();
  bool upright = false;
  // The scan's cut faces are its own grid's: when the import works on a turned grid they are
  // found, and measured, on the CT as it came (an oblique grid's crop faces, a gantry-tilted
  // stack's top and bottom, lie slanted across the turned one).
  Volume grid_P;  // the CT's geometry (no values)
  std::vector<CutFace> faces_P;
  LabelledAnatomy labelled;
  const bool have_labels = !c.labels.empty();
  std::vector<IntercostalSpace> layer_spaces[2];  // left, right
  std::vector<WallReach> layer_reach;             // their sides' walls
  bool layer_side[2] = {false, false};
  double layer_floor = 0.0;
  Mask heart;
  bool have_heart = false;
  std::string heart_note;  // an approximated heart says so
  std::vector<CutFace> cut_faces;
  double voxel = 0.0;                     // m^3
  int rays_kept = 0, rays_under_arm = 0;  // over the spaces found, out to the skin
};

// The model in the CT's state, built or loaded from the cache.
ImportedPatient ImportCtState(const std::string& case_dir, const CaseSpec& c,
                              const ImportOptions& options) {
  return CtImport(case_dir, c, options).Run();
}

}  // namespace

ImportedPatient ImportCase(const std::string& case_dir, const ImportOptions& options) {
  const CaseSpec c = ReadCase(case_dir);
  ImportedPatient out = ImportCtState(case_dir, c, options);
  out.ct_model = out.model;
  if (options.ct_state) return out;
  // The operation's world: a copy with the heart and the targets on it moved.
  auto operative = std::make_shared<PatientModel>(*out.model);
  ApplyOperativeState(c.operation, operative.get());
  std::ostringstream line;
  line << "operation: " << c.operation.Describe();
  const OperativeChange& change = operative->operative_change;
  if (!change.structures.empty() || !change.targets.empty()) {
    line << "; moved " << std::fixed << std::setprecision(1) << change.d_P.norm() * 1e3
         << " mm (patient frame " << change.d_P.x() * 1e3 << ", " << change.d_P.y() * 1e3 << ", "
         << change.d_P.z() * 1e3 << " mm):";
    for (const auto& n : change.structures) line << " " << n;
    for (const auto& n : change.targets) line << " " << n;
    line << "; fixed: the chest wall, skin, bones and the targets in the wall";
  }
  out.report.checks.push_back(line.str());
  out.model = std::move(operative);
  return out;
}

PatientModel ImportPatient(const std::string& case_dir, const ImportOptions& options) {
  return *ImportCase(case_dir, options).model;
}

}  // namespace trocar::patient
