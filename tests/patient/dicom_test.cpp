#include <gtest/gtest.h>
#include <gdcmImage.h>
#include <gdcmImageWriter.h>
#include <gdcmMediaStorage.h>
#include <vtkDICOMImageReader.h>
#include <vtkImageData.h>
#include <vtkNew.h>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/phantom.hpp"
#include "patient/volume.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

namespace fs = std::filesystem;
using patient::LoadVolume;
using patient::Volume;

// A fresh, empty scratch folder (not created).
std::string Scratch(const std::string& name) { return test::ScratchPath("dicom_" + name); }

// A small volume with integer values, rotated in-plane axes and a tilted third axis (a gantry
// tilt), seeded.
Volume RandomVolume(unsigned seed, bool integral = true) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  Volume v;
  v.size = Eigen::Vector3i(7 + seed % 5, 5 + seed % 4, 4 + seed % 3);
  const Eigen::Matrix3d R =
      Eigen::Quaterniond(u(rng), u(rng), u(rng), u(rng)).normalized().toRotationMatrix();
  const Eigen::Vector3d spacing(0.0007 + 0.0005 * std::abs(u(rng)),
                                0.0007 + 0.0005 * std::abs(u(rng)),
                                0.001 + 0.002 * std::abs(u(rng)));
  v.index_to_P = R * spacing.asDiagonal();
  v.index_to_P.col(2) += 0.2 * u(rng) * v.index_to_P.col(1);  // tilt
  v.origin_P = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.3;
  v.values.resize(v.voxel_count());
  for (auto& x : v.values) {
    x = static_cast<float>(std::round(1500 * u(rng)));
    if (!integral) x += 0.37f * static_cast<float>(u(rng));
  }
  v.hounsfield = true;
  return v;
}

void ExpectSameGeometry(const Volume& a, const Volume& b) {
  EXPECT_EQ(a.size, b.size);
  // DICOM decimal strings carry 16 characters: geometry to well under a micrometre.
  EXPECT_TRUE(test::CompareMatrices(a.index_to_P, b.index_to_P, 1e-9)) << a.index_to_P << "\n"
                                                                       << b.index_to_P;
  EXPECT_TRUE(test::CompareMatrices(a.origin_P, b.origin_P, 1e-9));
}

std::vector<std::string> SliceFiles(const std::string& dir) {
  std::vector<std::string> files;
  for (const auto& e : fs::directory_iterator(dir)) files.push_back(e.path().string());
  std::sort(files.begin(), files.end());
  return files;
}

std::string LoadError(const std::string& path) {
  try {
    LoadVolume(path);
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(DicomSeries, RoundTripsExplicitAndImplicitVrOverRandomGeometries) {
  for (unsigned seed = 0; seed < 12; ++seed) {
    SCOPED_TRACE(seed);
    const Volume v = RandomVolume(seed);
    patient::DicomWriteOptions options;
    options.implicit_vr = seed % 2 == 1;
    const std::string dir = Scratch("roundtrip");
    patient::WriteDicomSeries(v, dir, options);
    EXPECT_EQ(SliceFiles(dir).size(), static_cast<std::size_t>(v.size.z()));
    for (const auto& e : fs::directory_iterator(fs::path(dir).parent_path())) {
      EXPECT_EQ(e.path().filename().string().find("trocar_dicom_roundtrip.partial"), std::string::npos);
    }
    const Volume r = LoadVolume(dir);
    ExpectSameGeometry(v, r);
    EXPECT_EQ(r.values, v.values);
    EXPECT_TRUE(r.hounsfield);
    EXPECT_EQ(r.files.size(), static_cast<std::size_t>(v.size.z()));
  }
}

TEST(DicomSeries, NonIntegerValuesAreRescaledWithinHalfAStep) {
  const Volume v = RandomVolume(3, /*integral=*/false);
  const std::string dir = Scratch("rescaled");
  patient::WriteDicomSeries(v, dir);
  const Volume r = LoadVolume(dir);
  ExpectSameGeometry(v, r);
  const auto [lo, hi] = std::minmax_element(v.values.begin(), v.values.end());
  const double step = (*hi - *lo) / 65000.0;
  for (std::size_t n = 0; n < v.values.size(); ++n)
    EXPECT_NEAR(r.values[n], v.values[n], 0.51 * step + 1e-4);
}

TEST(DicomSeries, SliceOrderComesFromPositionsNotFileNames) {
  const Volume v = RandomVolume(5);
  const std::string dir = Scratch("shuffled");
  patient::WriteDicomSeries(v, dir);
  // Rename the slices so that name order is reversed, and drop a README beside them.
  const auto files = SliceFiles(dir);
  for (std::size_t n = 0; n < files.size(); ++n) {
    fs::rename(files[n], dir + "/IM" + std::to_string(100 - n));
  }
  WriteFileAtomically(dir + "/README.txt", "exported by hand\n");
  const Volume r = LoadVolume(dir);
  ExpectSameGeometry(v, r);
  EXPECT_EQ(r.values, v.values);
}

TEST(DicomSeries, PhantomAsDicomImportsToTheNrrdGeometryAndValues) {
  patient::PhantomParameters p;
  p.seed = 6;
  p.voxel_size = 0.004;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  const std::string dir = Scratch("phantom_case");
  patient::WritePhantomCase(ph, dir, patient::CtFormat::kDicom);
  EXPECT_NE(ReadTextFile(dir + "/patient.yaml").find("ct: ct\n"), std::string::npos);
  const Volume r = LoadVolume(dir + "/ct");
  ExpectSameGeometry(ph.ct, r);
  ASSERT_EQ(r.values.size(), ph.ct.values.size());
  double worst = 0;
  for (std::size_t n = 0; n < r.values.size(); ++n)
    worst = std::max(worst, double(std::abs(r.values[n] - ph.ct.values[n])));
  EXPECT_LT(worst, 0.05);  // HU survive the 16-bit encoding
  EXPECT_TRUE(r.hounsfield);
  // One file of the series names the series too.
  const Volume by_file = LoadVolume(SliceFiles(dir + "/ct")[3]);
  EXPECT_EQ(by_file.values, r.values);
}

// Runs a command; its exit status.
int RunQuiet(const std::string& command) { return std::system((command + " >/dev/null 2>&1").c_str()); }

// Each slice of `from` through gdcmconv with `options` into `to`.
void Gdcmconv(const std::string& from, const std::string& to, const std::string& options) {
  fs::create_directories(to);
  for (const auto& f : SliceFiles(from)) {
    const std::string out = to + "/" + fs::path(f).filename().string();
    ASSERT_EQ(RunQuiet("gdcmconv " + options + " '" + f + "' '" + out + "'"), 0) << options << " " << f;
  }
}

// The transfer syntax UID a file's meta header names.
std::string TransferSyntaxOf(const std::string& file) {
  const std::string bytes = ReadTextFile(file);
  for (const char* uid : {"1.2.840.10008.1.2.4.70", "1.2.840.10008.1.2.4.57", "1.2.840.10008.1.2.4.80",
                          "1.2.840.10008.1.2.4.90", "1.2.840.10008.1.2.5", "1.2.840.10008.1.2.1.99"}) {
    for (auto at = bytes.find(uid); at != std::string::npos; at = bytes.find(uid, at + 1)) {
      const char next = bytes[at + std::strlen(uid)];
      if (next != '.' && !std::isdigit(static_cast<unsigned char>(next))) return uid;
    }
  }
  return "uncompressed";
}

// The phantom's series compressed by GDCM's own tool in each lossless syntax imports voxel for
// voxel as the uncompressed one: the decoding is GDCM's, the geometry and order trocar's.
TEST(DicomSeries, CompressedSyntaxesImportVoxelForVoxel) {
  ASSERT_EQ(RunQuiet("gdcmconv --version"), 0) << "gdcmconv (libgdcm-tools) is missing";
  patient::PhantomParameters p;
  p.seed = 3;
  p.voxel_size = 0.005;
  const patient::Phantom ph = patient::GeneratePhantom(p);
  const std::string dir = Scratch("compress_src");
  patient::WriteDicomSeries(ph.ct, dir);
  const Volume plain = LoadVolume(dir);
  ASSERT_EQ(plain.size, ph.ct.size);
  struct Syntax {
    const char* options;
    const char* uid;
  };
  for (const Syntax& syntax : {Syntax{"--jpeg", "1.2.840.10008.1.2.4.70"},
                               Syntax{"--jpegls", "1.2.840.10008.1.2.4.80"},
                               Syntax{"--j2k", "1.2.840.10008.1.2.4.90"},
                               Syntax{"--rle", "1.2.840.10008.1.2.5"},
                               Syntax{"--deflated", "1.2.840.10008.1.2.1.99"}}) {
    SCOPED_TRACE(syntax.options);
    const std::string out = Scratch(std::string("compress") + syntax.options);
    Gdcmconv(dir, out, syntax.options);
    ASSERT_EQ(TransferSyntaxOf(SliceFiles(out)[1]), syntax.uid);  // really compressed
    const Volume r = LoadVolume(out);
    ExpectSameGeometry(plain, r);
    EXPECT_EQ(r.values, plain.values);
    EXPECT_TRUE(r.hounsfield);
    if (std::string(syntax.options) == "--j2k") {
      // A codestream without its start markers: GDCM cannot decode it, and the error says which
      // file and which syntax.
      const std::string file = SliceFiles(out)[2];
      std::string bytes = ReadTextFile(file);
      const auto at = bytes.find(std::string("\xFF\x4F\xFF\x51", 4));
      ASSERT_NE(at, std::string::npos);
      bytes.replace(at, 4, std::string(4, '\0'));
      WriteFileAtomically(file, bytes);
      const std::string m = LoadError(out);
      EXPECT_NE(m.find(file + ": transfer syntax 1.2.840.10008.1.2.4.90 (JPEG 2000 Lossless)"),
                std::string::npos)
          << m;
      EXPECT_NE(m.find("cannot decode"), std::string::npos) << m;
    }
    fs::remove_all(out);
  }
  fs::remove_all(dir);
}

// An enhanced multi-frame CT (one file, positions in per-frame functional groups, geometry and
// rescale in the shared ones), written by GDCM's own writer: the same volume, frame by frame.
TEST(DicomSeries, EnhancedMultiFrameCtImportsFrameByFrame) {
  for (unsigned seed = 0; seed < 4; ++seed) {
    SCOPED_TRACE(seed);
    Volume v = RandomVolume(seed);
    Eigen::Matrix3d axes;
    axes.col(0) = v.index_to_P.col(0).normalized();
    axes.col(1) = v.index_to_P.col(1).normalized();
    axes.col(2) = axes.col(0).cross(axes.col(1));
    const Eigen::Vector3d spacing(0.0007 + 0.0001 * seed, 0.0008, 0.0025);
    v.index_to_P = axes * spacing.asDiagonal();  // no tilt: frames along the normal
    const std::string dir = Scratch("enhanced" + std::to_string(seed));
    fs::create_directories(dir);
    gdcm::ImageWriter writer;
    gdcm::Image& image = writer.GetImage();
    image.SetNumberOfDimensions(3);
    const unsigned dims[3] = {unsigned(v.size.x()), unsigned(v.size.y()), unsigned(v.size.z())};
    image.SetDimensions(dims);
    image.SetPixelFormat(gdcm::PixelFormat::INT16);
    image.SetPhotometricInterpretation(gdcm::PhotometricInterpretation::MONOCHROME2);
    const Eigen::Vector3d origin_mm = v.origin_P * 1e3;
    image.SetOrigin(origin_mm.data());
    const double spacing_mm[3] = {spacing.x() * 1e3, spacing.y() * 1e3, spacing.z() * 1e3};
    image.SetSpacing(spacing_mm);
    const double cosines[6] = {axes(0, 0), axes(1, 0), axes(2, 0), axes(0, 1), axes(1, 1), axes(2, 1)};
    image.SetDirectionCosines(cosines);
    image.SetIntercept(-24);
    image.SetSlope(1);
    std::vector<std::int16_t> stored(v.values.size());
    for (std::size_t n = 0; n < stored.size(); ++n) stored[n] = static_cast<std::int16_t>(v.values[n] + 24);
    gdcm::DataElement pixels(gdcm::Tag(0x7fe0, 0x0010));
    pixels.SetByteValue(reinterpret_cast<const char*>(stored.data()),
                        static_cast<std::uint32_t>(stored.size() * 2));
    image.SetDataElement(pixels);
    const gdcm::MediaStorage ms(gdcm::MediaStorage::EnhancedCTImageStorage);
    gdcm::DataElement sop(gdcm::Tag(0x0008, 0x0016));
    sop.SetByteValue(ms.GetString(), static_cast<std::uint32_t>(std::strlen(ms.GetString())));
    writer.GetFile().GetDataSet().Insert(sop);
    const std::string file = dir + "/enhanced.dcm";
    writer.SetFileName(file.c_str());
    ASSERT_TRUE(writer.Write());
    ASSERT_NE(ReadTextFile(file).find(std::string("\x00\x52\x29\x92", 4)), std::string::npos)
        << "no shared functional groups (5200,9229)";
    const Volume r = LoadVolume(dir);
    EXPECT_EQ(r.size, v.size);
    EXPECT_TRUE(test::CompareMatrices(r.index_to_P, v.index_to_P, 1e-9)) << r.index_to_P;
    EXPECT_TRUE(test::CompareMatrices(r.origin_P, v.origin_P, 1e-9));
    EXPECT_EQ(r.values, v.values);
    EXPECT_EQ(r.files, std::vector<std::string>{file});
    // The file named alone is the whole series too.
    EXPECT_EQ(LoadVolume(file).values, v.values);
    fs::remove_all(dir);
  }
}

// A real series stored as JPEG 2000 lossless (TotalSegmentator's example): read through GDCM onto
// the grid of the label map TotalSegmentator made from it, with the body in Hounsfield units.
TEST(DicomSeries, RealJpeg2000SeriesImportsOnItsLabelMapsGrid) {
  const std::string dicom = test::SharedDataPath("ct/totalseg-dicom-j2k/dicom");
  const std::string labels = test::SharedDataPath("ct/totalseg-dicom-j2k/example_seg_dicom.nii.gz");
  TROCAR_REQUIRE_SHARED_FILE(labels);
  const Volume ct = LoadVolume(dicom);
  EXPECT_EQ(ct.size, Eigen::Vector3i(512, 512, 20));
  EXPECT_TRUE(ct.hounsfield);
  const Eigen::Vector3d spacing = ct.spacing();
  EXPECT_NEAR(spacing.x(), 0.000977, 2e-6);
  EXPECT_NEAR(spacing.z(), 0.002, 1e-6);
  const Volume seg = LoadVolume(labels);
  ASSERT_EQ(seg.size, ct.size);
  // Every CT voxel centre is a label map voxel centre (the two files may order their axes
  // differently: TotalSegmentator's NIfTI runs the rows the other way).
  long labelled_n = 0;
  double labelled = 0, corner = 0;
  double worst = 0;
  for (int k = 0; k < ct.size.z(); ++k) {
    for (int j = 0; j < ct.size.y(); ++j) {
      for (int i = 0; i < ct.size.x(); ++i) {
        const Eigen::Vector3d q = seg.IndexOf(ct.PatientPoint(i, j, k));
        const Eigen::Vector3d r = q.array().round();
        worst = std::max(worst, (q - r).cwiseAbs().maxCoeff());
        ASSERT_TRUE((r.array() >= 0).all() && (r.array() < seg.size.cast<double>().array()).all())
            << i << " " << j << " " << k;
        if (seg.at(int(r.x()), int(r.y()), int(r.z())) > 0) {
          labelled += ct.at(i, j, k);
          ++labelled_n;
        }
      }
    }
  }
  EXPECT_LT(worst, 0.05);
  const long n_labelled = labelled_n;
  corner = ct.at(2, 2, 10);
  ASSERT_GT(n_labelled, 10000);
  EXPECT_GT(labelled / n_labelled, -100.0);
  EXPECT_LT(corner, -900.0);
}

// The real chest, written as a series and read back: same grid, same values, still raw 8-bit.
TEST(DicomSeries, Lidc2ChestRoundTrips) {
  const std::string path = test::SharedDataPath("ct/lidc2/ct.nhdr");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const Volume v = LoadVolume(path);
  const std::string dir = Scratch("lidc2");
  patient::WriteDicomSeries(v, dir, {});
  const Volume r = LoadVolume(dir);
  ExpectSameGeometry(v, r);
  EXPECT_EQ(r.values, v.values);
  EXPECT_FALSE(r.hounsfield);
  EXPECT_EQ(r.files.size(), 133u);
  fs::remove_all(dir);
}

TEST(DicomSeries, AFolderWithTwoSeriesIsListedAndAFileChoosesOne) {
  const Volume a = RandomVolume(1), b = RandomVolume(2);
  const std::string dir = Scratch("two"), other = Scratch("other");
  patient::WriteDicomSeries(a, dir);
  patient::WriteDicomSeries(b, other);
  for (const auto& f : SliceFiles(other))
    fs::rename(f, dir + "/b_" + fs::path(f).filename().string());
  const std::string message = LoadError(dir);
  EXPECT_NE(message.find("holds 2 series"), std::string::npos) << message;
  EXPECT_NE(message.find("give one of a series' files"), std::string::npos) << message;
  const Volume chosen = LoadVolume(dir + "/b_slice_0001.dcm");
  EXPECT_EQ(chosen.values, b.values);
  const Volume first = LoadVolume(dir + "/slice_0002.dcm");
  EXPECT_EQ(first.values, a.values);
}

TEST(DicomSeries, BadSeriesAreClearErrorsNamingTheFile) {
  const Volume v = RandomVolume(7);
  ASSERT_GE(v.size.z(), 5);
  auto fresh = [&](const std::string& name) {
    const std::string dir = Scratch(name);
    patient::WriteDicomSeries(v, dir);
    return dir;
  };
  {  // A missing slice in the middle.
    const std::string dir = fresh("missing");
    fs::remove(dir + "/slice_0003.dcm");
    const std::string m = LoadError(dir);
    EXPECT_NE(m.find("slice_0004.dcm"), std::string::npos) << m;
    EXPECT_NE(m.find("missing slice or uneven spacing"), std::string::npos) << m;
  }
  {  // The same slice twice.
    const std::string dir = fresh("duplicate");
    fs::copy_file(dir + "/slice_0002.dcm", dir + "/slice_0002_copy.dcm");
    const std::string m = LoadError(dir);
    EXPECT_NE(m.find("same position"), std::string::npos) << m;
  }
  {  // A truncated slice.
    const std::string dir = fresh("truncated");
    const std::string bytes = ReadTextFile(dir + "/slice_0002.dcm");
    WriteFileAtomically(dir + "/slice_0002.dcm", bytes.substr(0, bytes.size() / 2));
    const std::string m = LoadError(dir);
    EXPECT_NE(m.find("slice_0002.dcm"), std::string::npos) << m;
    EXPECT_NE(m.find("truncated"), std::string::npos) << m;
  }
  {  // A transfer syntax that lies (RLE announced, plain pixels stored; the same UID length):
     // GDCM reads the pixel data for what it is, an uncompressed value of defined length.
    const std::string dir = fresh("compressed");
    std::string bytes = ReadTextFile(dir + "/slice_0001.dcm");
    const std::string from("1.2.840.10008.1.2.1\0", 20), to("1.2.840.10008.1.2.5\0", 20);
    const auto at = bytes.find(from);
    ASSERT_NE(at, std::string::npos);
    bytes.replace(at, from.size(), to);
    WriteFileAtomically(dir + "/slice_0001.dcm", bytes);
    EXPECT_EQ(LoadVolume(dir).values, v.values);
  }
  {  // A bits-allocated value GDCM would assert on is an error naming the element.
    const std::string dir = fresh("bits");
    std::string bytes = ReadTextFile(dir + "/slice_0001.dcm");
    const std::string from("\x28\x00\x00\x01US\x02\x00\x10\x00", 10);
    const auto at = bytes.find(from);
    ASSERT_NE(at, std::string::npos);
    bytes[at + 8] = 12;
    WriteFileAtomically(dir + "/slice_0001.dcm", bytes);
    const std::string m = LoadError(dir);
    EXPECT_NE(m.find("slice_0001.dcm: bits allocated (0028,0100) is 12"), std::string::npos) << m;
  }
  {  // Only one slice.
    const std::string dir = fresh("single");
    for (const auto& f : SliceFiles(dir)) {
      if (f.find("slice_0001") == std::string::npos) fs::remove(f);
    }
    EXPECT_NE(LoadError(dir).find("at least two"), std::string::npos);
  }
  {  // No DICOM at all.
    const std::string dir = Scratch("empty");
    fs::create_directories(dir);
    WriteFileAtomically(dir + "/notes.txt", "nothing here\n");
    const std::string m = LoadError(dir);
    EXPECT_NE(m.find("no DICOM image slices among its 1 files"), std::string::npos) << m;
  }
  // A folder that cannot be made (its parent is a file): an error, and nothing left behind.
  const std::string blocker = Scratch("blocker");
  WriteFileAtomically(blocker, "a file, not a folder\n");
  try {
    patient::WriteDicomSeries(v, blocker + "/series");
    ADD_FAILURE() << "wrote under a file";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot create the folder"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ReadTextFile(blocker), "a file, not a folder\n");
  // The writer refuses to mix a new series into an existing one.
  const std::string dir = fresh("occupied");
  try {
    patient::WriteDicomSeries(v, dir);
    ADD_FAILURE() << "wrote into a non-empty folder";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("not an empty folder"), std::string::npos) << e.what();
  }
}

// A file that passes trocar's structure walk but makes Debian's GDCM assert (a fuzz finding:
// an explicit-VR element GDCM's reader says "should not happen" about) is decoded in a child
// process: the import ends in an error naming the file and what GDCM said, and trocar goes on.
TEST(DicomSeries, AFileThatMakesGdcmAbortIsAnErrorNamingItNotACrash) {
  const std::string finding =
      std::string(TROCAR_SOURCE_DIR) + "/tests/fuzz/regressions/dicom/gdcm-assert-vr16-explicit.dcm";
  for (int run = 0; run < 2; ++run) {  // the reader is whole again after a child died
    const std::string m = LoadError(finding);
    EXPECT_NE(m.find("gdcm-assert-vr16-explicit.dcm: the decoder crashed on it (signal 6"),
              std::string::npos) << m;
    EXPECT_NE(m.find("Should not happen"), std::string::npos) << m;
  }
  // Among good slices, the same file spoils the series by name.
  const Volume v = RandomVolume(5);
  const std::string dir = Scratch("gdcm-abort");
  patient::WriteDicomSeries(v, dir);
  fs::copy_file(finding, dir + "/slice_9999.dcm");
  const std::string m = LoadError(dir);
  EXPECT_NE(m.find("slice_9999.dcm: the decoder crashed"), std::string::npos) << m;
  fs::remove(dir + "/slice_9999.dcm");
  EXPECT_EQ(LoadVolume(dir).values, v.values);
}

// An independent reader (VTK's DICOMParser) sees the same grid and the same stored values.
TEST(DicomSeries, VtksReaderReadsWhatTrocarWrites) {
  Volume v = RandomVolume(4);
  // VTK's reader keeps no directions, and takes pixel spacing's first value (DICOM's row
  // spacing, along j) for x: equal in-plane spacing sidesteps that known quirk.
  v.index_to_P = Eigen::Vector3d(0.0008, 0.0008, 0.0025).asDiagonal();
  const std::string dir = Scratch("vtk");
  patient::WriteDicomSeries(v, dir);
  vtkNew<vtkDICOMImageReader> reader;
  reader->SetDirectoryName(dir.c_str());
  reader->Update();
  vtkImageData* image = reader->GetOutput();
  int dims[3];
  image->GetDimensions(dims);
  EXPECT_EQ(Eigen::Vector3i(dims[0], dims[1], dims[2]), v.size);
  double spacing[3];
  image->GetSpacing(spacing);
  EXPECT_NEAR(spacing[0], 0.8, 1e-6);
  EXPECT_NEAR(spacing[1], 0.8, 1e-6);
  EXPECT_NEAR(spacing[2], 2.5, 1e-6);
  // VTK's reader keeps the position as a float: 2^-16 mm apart at 242 mm (clang's build rounds the
  // written origin to its last float step, gcc's happened to hit one).
  EXPECT_NEAR(reader->GetImagePositionPatient()[0], v.origin_P.x() * 1e3,
              1e-7 * std::abs(v.origin_P.x() * 1e3) + 1e-6);
  // vtkDICOMImageReader puts the first row at the bottom (y flipped) and, keeping its grid
  // right-handed, the slices in reverse order.
  long mismatches = 0;
  for (int k = 0; k < v.size.z(); ++k) {
    for (int j = 0; j < v.size.y(); ++j) {
      for (int i = 0; i < v.size.x(); ++i) {
        const double vtk =
            image->GetScalarComponentAsDouble(i, v.size.y() - 1 - j, v.size.z() - 1 - k, 0);
        mismatches += vtk != v.at(i, j, k);
      }
    }
  }
  EXPECT_EQ(mismatches, 0);
}

// Random byte corruption of one slice: an error or a volume, never a crash or a hang.
TEST(DicomSeries, CorruptedBytesGiveErrorsNotCrashes) {
  const Volume v = RandomVolume(9);
  const std::string clean = Scratch("fuzz_clean");
  patient::WriteDicomSeries(v, clean);
  const std::string original = ReadTextFile(clean + "/slice_0002.dcm");
  const std::size_t header =
      original.size() - 2 * static_cast<std::size_t>(v.size.x()) * v.size.y();
  std::mt19937 rng(11);
  int errors = 0;
  for (int trial = 0; trial < 300; ++trial) {
    std::string bytes = original;
    std::uniform_int_distribution<std::size_t> where(128, header + 8);
    const int flips = 1 + trial % 4;
    for (int f = 0; f < flips; ++f) bytes[where(rng)] = static_cast<char>(rng() & 0xFF);
    WriteFileAtomically(clean + "/slice_0002.dcm", bytes);
    try {
      const Volume r = LoadVolume(clean);
      EXPECT_EQ(static_cast<long>(r.values.size()), r.voxel_count());
    } catch (const Error& e) {
      ++errors;
      EXPECT_FALSE(std::string(e.what()).empty());
    }
  }
  EXPECT_GT(errors, 30);  // most header damage is noticed
}

}  // namespace
}  // namespace trocar
