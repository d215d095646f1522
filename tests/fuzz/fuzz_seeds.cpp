// Writes the seed corpora the fuzz targets start from (scripts/fuzz runs it): tiny valid files of
// every binary format, made by trocar's own writers, so that no binary file is committed. Text
// formats are seeded from the repository's robots, patients and markups by scripts/fuzz.
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>

#include "common/file_util.hpp"
#include "control/device_input.hpp"
#include "patient/markups.hpp"
#include "patient/model_cache.hpp"
#include "patient/patient_model.hpp"
#include "patient/volume.hpp"

namespace fs = std::filesystem;
using namespace trocar;

namespace {

patient::Volume Tiny() {
  patient::Volume v;
  v.size = Eigen::Vector3i(4, 3, 2);
  v.index_to_P = Eigen::Vector3d(0.001, 0.0012, 0.002).asDiagonal();
  v.origin_P = Eigen::Vector3d(-0.01, 0.02, 0.1);
  for (int i = 0; i < 24; ++i) v.values.push_back(static_cast<float>(i * 100 - 1000));
  v.hounsfield = true;
  return v;
}

void Copy(const std::string& from, const std::string& to) {
  fs::create_directories(fs::path(to).parent_path());
  fs::copy_file(from, to, fs::copy_options::overwrite_existing);
}

void Text(const std::string& to, const std::string& text) {
  fs::create_directories(fs::path(to).parent_path());
  std::ofstream(to, std::ios::binary) << text;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::cerr << "usage: fuzz_seeds CORPUS_DIR\n";
    return 2;
  }
  const std::string out = argv[1];
  const std::string tmp = out + "/.work";
  fs::remove_all(tmp);
  fs::create_directories(tmp);
  const patient::Volume v = Tiny();
  patient::WriteNrrd(v, tmp + "/lps.nrrd");
  patient::WriteNrrd(v, tmp + "/ras.nrrd", true);
  Copy(tmp + "/lps.nrrd", out + "/nrrd/lps.nrrd");
  Copy(tmp + "/ras.nrrd", out + "/nrrd/ras.nrrd");
  Text(out + "/nrrd/raw.nrrd",
       "NRRD0004\ntype: short\ndimension: 3\nspace: left-posterior-superior\nsizes: 2 2 2\n"
       "space directions: (1,0,0) (0,1,0) (0,0,2.5)\nspace origin: (0,0,0)\nendian: big\n"
       "encoding: raw\n\n" + std::string(16, '\x01'));
  // A scene file and a device file as trocar writes and documents them (text, tiny).
  Text(out + "/scene/scene.json",
       "{\"format\": \"trocar-scene\", \"version\": 1, \"case\": \"c\", \"plan\": \"\", "
       "\"robot\": \"r.yaml\", \"plan_index\": 1, \"X_WB\": [[1,0,0,0.5],[0,1,0,0],[0,0,1,0],"
       "[0,0,0,1]], \"q\": {\"j1\": 0.1}, \"camera\": {\"position\": [2,-2,2], \"focal_point\": "
       "[0,0,1], \"view_up\": [0,0,1], \"view_angle_deg\": 30}, \"style\": {\"background\": "
       "[0,0,0], \"flat\": true, \"patient_triangles\": 50000, \"colours\": {\"heart\": [1,0,0]}, "
       "\"opacities\": {\"skin\": 0.3}, \"visible\": {\"table\": false}}}\n");
  Text(out + "/device/devices.yaml",
       "devices:\n  - {name: left,  arm: psm1, units: mm, scale: 3, device_to_camera_rpy: [0, 0, 90 deg]}\n"
       "  - {name: right, arm: psm2, units: m}\n  - {name: senior, pointer: true}\n");
  // MetaImage, raw and zlib.
  Text(out + "/metaimage/raw.mha",
       "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementSpacing = 1 1 2\n"
       "Offset = 0 0 0\nTransformMatrix = 1 0 0 0 1 0 0 0 1\nElementType = MET_SHORT\n"
       "ElementDataFile = LOCAL\n" + std::string(16, '\x02'));
  // NIfTI: the tiny volume as the test suite's writer makes it (sform), uncompressed.
  {
    std::string h(352, '\0');
    auto put = [&](std::size_t at, const void* data, std::size_t n) { std::memcpy(&h[at], data, n); };
    const std::int32_t size = 348;
    put(0, &size, 4);
    const std::int16_t dims[8] = {3, 4, 3, 2, 1, 1, 1, 1};
    put(40, dims, 16);
    const std::int16_t datatype = 4, bitpix = 16, qform = 1, sform = 1;
    put(70, &datatype, 2);
    put(72, &bitpix, 2);
    const float pixdim[4] = {1, 1, 1.2f, 2};
    put(76, pixdim, 16);
    const float offset = 352;
    put(108, &offset, 4);
    put(252, &qform, 2);
    put(254, &sform, 2);
    const float quatern[6] = {0, 0, 0.7071f, 10, 20, 30};
    put(256, quatern, 24);
    for (int r = 0; r < 3; ++r) {
      float row[4] = {0, 0, 0, 5};
      row[r] = r == 0 ? -1.0f : r == 1 ? -1.2f : 2.0f;
      put(280 + 16 * r, row, 16);
    }
    put(344, "n+1", 4);
    std::string voxels;
    for (int i = 0; i < 24; ++i) {
      const std::int16_t x = static_cast<std::int16_t>(i * 100 - 1000);
      voxels.append(reinterpret_cast<const char*>(&x), 2);
    }
    Text(out + "/nifti/tiny.nii", h + voxels);
  }
  // DICOM: one slice of a two-slice series, explicit and implicit VR.
  for (const bool implicit : {false, true}) {
    const std::string folder = tmp + (implicit ? "/implicit" : "/explicit");
    patient::DicomWriteOptions options;
    options.implicit_vr = implicit;
    patient::WriteDicomSeries(v, folder, options);
    int n = 0;
    for (const auto& entry : fs::directory_iterator(folder)) {
      Copy(entry.path().string(), out + "/dicom/" + (implicit ? "implicit" : "explicit") +
                                      std::to_string(n++) + ".dcm");
      break;
    }
  }
  // The model cache: a model with one small structure, a target and a candidate.
  {
    patient::PatientModel m;
    m.name = "seed";
    m.ct_source = "ct.nrrd";
    patient::Structure s;
    s.name = "skin";
    s.volume = 1e-3;
    s.mesh.vertices = {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.1, 0, 0), Eigen::Vector3d(0, 0.1, 0),
                       Eigen::Vector3d(0, 0, 0.1)};
    s.mesh.triangles = {Eigen::Vector3i(0, 2, 1), Eigen::Vector3i(0, 1, 3), Eigen::Vector3i(0, 3, 2),
                        Eigen::Vector3i(1, 2, 3)};
    m.structures.push_back(s);
    patient::Target t;
    t.name = "LAD";
    t.points = {Eigen::Vector3d(0.01, 0.02, 0.03)};
    t.normals = {Eigen::Vector3d(0, 0, 1)};
    m.targets.push_back(t);
    patient::ImportReport report;
    report.warnings = {"a warning"};
    Text(out + "/model_cache/model.bin", patient::SerializeModel(m, report, 0x1234));
  }
  // Recorded hand motion.
  {
    std::vector<control::DeviceSample> samples(3);
    for (int i = 0; i < 3; ++i) {
      samples[i].t = 0.001 * i;
      samples[i].X_DH.translation() = Eigen::Vector3d(0.001 * i, 0, 0);
    }
    samples[1].clutch = true;
    control::WriteDeviceCsv(tmp + "/motion.csv", samples);
    Copy(tmp + "/motion.csv", out + "/teleop_csv/motion.csv");
  }
  // Label maps: a Slicer segmentation and a TotalSegmentator names sidecar.
  Text(out + "/label_map/seg.seg.nrrd",
       "NRRD0004\ntype: unsigned char\ndimension: 3\nspace: left-posterior-superior\n"
       "sizes: 2 2 2\nspace directions: (1,0,0) (0,1,0) (0,0,1)\nspace origin: (0,0,0)\n"
       "encoding: raw\nSegment0_Name:=rib_left_5\nSegment0_LabelValue:=1\nSegment0_Layer:=0\n"
       "Segment1_Name:=heart\nSegment1_LabelValue:=2\nSegment1_Layer:=0\n\n" +
           std::string("\x00\x01\x02\x01\x00\x01\x02\x00", 8));
  Text(out + "/label_map/names.json", "{\"1\": \"rib_left_5\", \"2\": \"heart\", \"3\": \"aorta\"}");
  // A plan's skeleton (docs/plan-format.md) naming a case and robot that are not there.
  Text(out + "/plan/plan.json",
       R"({"format": "trocar-plan", "version": 2, "inputs": {"case": "no-case", "robot": "no-robot.yaml",
 "case_hash": "fnv1a64:0000000000000000", "robot_hash": "fnv1a64:0000000000000000",
 "patient_model_hash": "fnv1a64:0000000000000000"}, "robot": {"arms": [{"name": "psm1",
 "rcm_frame": "psm1_rcm", "role": "instrument"}]}, "scoring": {"ik_tolerance_m": 0.001,
 "scope_half_fov_deg": 35, "scope_min_distance_m": 0.02, "scope_max_distance_m": 0.15},
 "plans": [{"rank": 1, "score": 0.5, "cart": {"x": 0, "y": -0.8, "yaw_deg": 90}, "ports": []}]})");
  fs::remove_all(tmp);
  std::cout << "fuzz seeds written to " << out << "\n";
  return 0;
}
