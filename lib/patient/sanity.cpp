#include "patient/sanity.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace trocar::patient {

namespace {

std::string Percent(double fraction) {
  std::ostringstream s;
  s << std::lround(100.0 * fraction) << "%";
  return s.str();
}

// The heart's centroid, and the lungs' (air inside the body) centroid and head-foot extent (0, 0
// with fewer than 1000 voxels of lung).
struct Centroids {
  Eigen::Vector3d heart = Eigen::Vector3d::Zero(), lung = Eigen::Vector3d::Zero();
  double lung_lo = HUGE_VAL, lung_hi = -HUGE_VAL;
};

Centroids MeasureCentroids(const Volume& ct, const Segmentation& seg, const Mask* heart,
                           bool with_heart) {
  Centroids c;
  long nh = 0, nl = 0;
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const long n = ct.Index(i, j, k);
        const bool in_heart = with_heart && heart->inside[n];
        const bool lung = seg.body.inside[n] && ct.values[n] <= seg.body_threshold;
        if (!in_heart && !lung) continue;
        const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
        if (in_heart) {
          c.heart += p;
          ++nh;
        }
        if (lung) {
          c.lung += p;
          ++nl;
          c.lung_lo = std::min(c.lung_lo, p.z());
          c.lung_hi = std::max(c.lung_hi, p.z());
        }
      }
    }
  }
  if (nh > 0) c.heart /= static_cast<double>(nh);
  if (nl > 0) c.lung /= static_cast<double>(nl);
  if (nl < 1000) c.lung_lo = c.lung_hi = 0.0;
  return c;
}

// Front-back: the vertebral column is the bulk of the bone in the midline band, behind the
// body's centre; in front there is only the sternum (and at most some contrast).
void FrontBackBySpine(const Volume& ct, const Segmentation& seg, double midline_x,
                      OrientationCheck* out) {
  const Eigen::Vector3d centre = 0.5 * (seg.body_min_P + seg.body_max_P);
  const Eigen::Vector3d half = 0.5 * (seg.body_max_P - seg.body_min_P);
  long behind = 0, in_front = 0;
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const long n = ct.Index(i, j, k);
        if (!seg.bone.inside[n]) continue;
        const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
        if (std::abs(p.x() - midline_x) > 0.15 * half.x()) continue;
        (p.y() > centre.y() ? behind : in_front) += 1;
      }
    }
  }
  const long midline = behind + in_front;
  if (midline > 0) {
    const double back = static_cast<double>(behind) / static_cast<double>(midline);
    if (back >= 0.65) out->anterior_posterior = +1;
    if (back <= 0.35) out->anterior_posterior = -1;
    out->findings.push_back(
        "spine: " + Percent(back) + " of the midline bone lies behind the body's centre" +
        (out->anterior_posterior > 0   ? " (spine at the back: front-back as the header says)"
         : out->anterior_posterior < 0 ? " (the spine lies in front: front-back flipped)"
                                       : " (undecided)"));
  } else {
    out->findings.push_back("spine: no bone in the midline band (front-back undecided)");
  }
}

// The heart lies in front of the lungs' centre (against the front chest wall).
void FrontBackByHeart(const Centroids& c, OrientationCheck* out) {
  const double ahead = c.lung.y() - c.heart.y();
  const int vote = ahead >= 0.01 ? +1 : ahead <= -0.01 ? -1 : 0;
  // A heart behind the lungs while the spine lies at the back as the header says is no heart
  // where a heart lies (contrast in a kidney or the bowel of an abdominal scan, taken for the
  // chambers): the header is not judged by it, left-right included. The other disagreement
  // (the midline bone in front, the heart in front too) leaves front-back undecided: in a crop
  // that cuts the spine off, the midline bone is the sternum and the heart is right.
  out->heart_misplaced = out->anterior_posterior > 0 && vote < 0;
  std::ostringstream s;
  s << "heart: " << std::lround(std::abs(ahead) * 1e3) << " mm "
    << (ahead >= 0 ? "in front of" : "behind") << " the lungs' centre"
    << (out->heart_misplaced ? " (behind, the spine at the back: not a heart where a heart lies, "
                               "not used to judge the header)"
        : vote > 0           ? " (front-back as the header says)"
        : vote < 0           ? " (behind: front-back flipped)"
                             : " (undecided)");
  out->findings.push_back(s.str());
  if (out->anterior_posterior == 0) out->anterior_posterior = vote;  // the spine undecided
  if (out->anterior_posterior != vote && vote != 0 && !out->heart_misplaced)
    out->anterior_posterior = 0;  // cues disagree
}

// Head-foot: a rib runs down from its back end to its front end (the rib cage's slope), so
// along each lateral bone piece height rises toward the back. The back is where the spine is.
void HeadFootByRibs(const Volume& ct, const Segmentation& seg, OrientationCheck* out) {
  const double back_sign = out->anterior_posterior < 0 ? -1.0 : 1.0;
  double rising = 0.0, falling = 0.0;
  int pieces = 0;
  std::vector<double> sums;  // per label: n, y, z, yy, yz
  for (const auto* side : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
    for (const Component& c : *side) sums.resize(std::max<std::size_t>(sums.size(), 5 * (c.label + 1)), 0.0);
  }
  if (!sums.empty() && !seg.bones.labels.empty()) {
    std::vector<std::uint8_t> lateral(sums.size() / 5, 0);
    for (const auto* side : {&seg.bones.ribs_left, &seg.bones.ribs_right}) {
      for (const Component& c : *side) lateral[c.label] = 1;
    }
    for (int k = 0; k < ct.size.z(); ++k) {
      for (int j = 0; j < ct.size.y(); ++j) {
        for (int i = 0; i < ct.size.x(); ++i) {
          const int label = seg.bones.labels[ct.Index(i, j, k)];
          if (label <= 0 || label >= static_cast<int>(lateral.size()) || !lateral[label]) continue;
          const Eigen::Vector3d p = ct.PatientPoint(i, j, k);
          const double y = back_sign * p.y(), z = p.z();
          double* s = &sums[5 * label];
          s[0] += 1;
          s[1] += y;
          s[2] += z;
          s[3] += y * y;
          s[4] += y * z;
        }
      }
    }
    for (std::size_t label = 0; label < lateral.size(); ++label) {
      const double* s = &sums[5 * label];
      if (!lateral[label] || s[0] < 20) continue;
      const double var = s[3] / s[0] - (s[1] / s[0]) * (s[1] / s[0]);
      if (var <= 1e-8) continue;  // no front-back extent: not rib-like
      const double slope = (s[4] / s[0] - (s[1] / s[0]) * (s[2] / s[0])) / var;
      // Rib-like pieces only: reaching 3 cm or more front to back (a rib's arc; not a vertebra's
      // process, not a shoulder blade's edge), and sloping (flat pieces say nothing).
      if (4.0 * std::sqrt(var) < 0.03 || std::abs(slope) < 0.05) continue;
      ++pieces;
      (slope > 0 ? rising : falling) += 1.0;
    }
  }
  if (pieces >= 3) {
    const double up = rising / (rising + falling);
    if (up >= 0.7) out->superior_inferior = +1;
    if (up <= 0.3) out->superior_inferior = -1;
    out->findings.push_back("ribs: " + Percent(up) + " of " + std::to_string(pieces) +
                            " rib-like lateral bone pieces rise toward the back" +
                            (out->superior_inferior > 0 ? " (head up as the header says)"
                             : out->superior_inferior < 0
                                 ? " (the ribs rise toward the front: head-foot flipped)"
                                 : " (undecided)"));
  } else {
    out->findings.push_back(
        "ribs: fewer than 3 rib-like lateral bone pieces (head-foot undecided)");
  }
}

// Left-right: the heart lies left of the midline (LPS +x).
void LeftRightByHeart(const Centroids& c, double midline_x, OrientationCheck* out) {
  const double left = c.heart.x() - midline_x;
  if (left >= 0.01) out->left_right = +1;
  if (left <= -0.01) out->left_right = -1;
  std::ostringstream s;
  s << "heart: centre " << std::lround(std::abs(left) * 1e3) << " mm "
    << (left >= 0 ? "left" : "right") << " of the body's midline"
    << (out->left_right > 0   ? " (left-right as the header says)"
        : out->left_right < 0 ? " (right of the midline: a mirrored header, or dextrocardia)"
                              : " (undecided)");
  out->findings.push_back(s.str());
}

// Left-right: labelled left ribs on the left.
void LeftRightByLabels(const Segmentation& seg, OrientationCheck* out) {
  double left = 0.0, right = 0.0;
  for (const auto& c : seg.bones.ribs_left) left += c.centroid_P.x();
  for (const auto& c : seg.bones.ribs_right) right += c.centroid_P.x();
  left /= static_cast<double>(seg.bones.ribs_left.size());
  right /= static_cast<double>(seg.bones.ribs_right.size());
  const int labelled = left > right ? +1 : -1;
  out->findings.push_back(
      std::string("labelled ribs: the left ribs lie ") +
      (labelled > 0 ? "left (LPS +x) of the right ones" : "right of the right ones: mirrored"));
  if (out->left_right == 0 || labelled < 0) out->left_right = labelled;
}

}  // namespace

OrientationCheck CheckOrientation(const Volume& ct, const Segmentation& seg, const Mask* heart) {
  OrientationCheck out;
  // The body's midline: its axis (Segmentation::axis_P), at the spine when a crop face or an arm
  // pulls the body's box aside (a heart-centred cardiac field of view).
  const double midline_x = seg.axis_P.x();
  const bool with_heart = heart != nullptr && heart->count() > 0;
  const Centroids c = MeasureCentroids(ct, seg, heart, with_heart);
  FrontBackBySpine(ct, seg, midline_x, &out);
  if (with_heart && c.lung_hi > c.lung_lo) FrontBackByHeart(c, &out);
  HeadFootByRibs(ct, seg, &out);
  if (with_heart && !out.heart_misplaced) LeftRightByHeart(c, midline_x, &out);
  if (seg.bones.numbered && !seg.bones.ribs_left.empty() && !seg.bones.ribs_right.empty())
    LeftRightByLabels(seg, &out);
  return out;
}

std::vector<CutFace> FindCutFaces(const Volume& ct, const Mask& body, double min_fraction) {
  std::vector<CutFace> faces;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = axis == 0 ? 1 : 0, w = axis == 2 ? 1 : 2;
    // Which way the index axis runs in the patient (LPS): its dominant component.
    const Eigen::Vector3d dir = ct.index_to_P.col(axis);
    int along = 0;
    dir.cwiseAbs().maxCoeff(&along);
    static const char* kPositive[3] = {"left", "posterior", "superior"};
    static const char* kNegative[3] = {"right", "anterior", "inferior"};
    for (const bool high : {false, true}) {
      long inside = 0;
      Eigen::Vector3i ijk;
      ijk[axis] = high ? ct.size[axis] - 1 : 0;
      for (int b = 0; b < ct.size[w]; ++b) {
        for (int a = 0; a < ct.size[u]; ++a) {
          ijk[u] = a;
          ijk[w] = b;
          inside += body.inside[ct.Index(ijk.x(), ijk.y(), ijk.z())] != 0;
        }
      }
      const double fraction = static_cast<double>(inside) / (static_cast<double>(ct.size[u]) * ct.size[w]);
      if (inside == 0 || fraction < min_fraction) continue;
      const bool positive = (dir[along] > 0) == high;
      faces.push_back({positive ? kPositive[along] : kNegative[along], axis, high, fraction});
    }
  }
  auto rank = [](const CutFace& f) {
    static const char* kOrder[6] = {"right",     "left",     "anterior",
                                    "posterior", "superior", "inferior"};
    return std::find(kOrder, kOrder + 6, f.name) - kOrder;
  };
  std::stable_sort(faces.begin(), faces.end(),
                   [&](const CutFace& a, const CutFace& b) { return rank(a) < rank(b); });
  return faces;
}

double DistanceToCutFace(const Volume& ct, const CutFace& face, const Eigen::Vector3d& p_P) {
  const Eigen::Vector3d ijk = ct.index_to_P.inverse() * (p_P - ct.origin_P);
  const double h = ct.index_to_P.col(face.axis).norm();
  // The face lies half a voxel beyond the outermost voxel centres.
  return (face.high ? (ct.size[face.axis] - 0.5 - ijk[face.axis]) : (ijk[face.axis] + 0.5)) * h;
}

}  // namespace trocar::patient
