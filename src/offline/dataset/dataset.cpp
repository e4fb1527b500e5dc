#include "simstack/offline/dataset/dataset.h"

#include <H5Cpp.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "simstack/offline/piles/mesh_catalogue.h"

namespace simstack {

const char* const kObjectColumns =
    "kind(0=superquadric,1=mesh),catalogue_index,a1,a2,a3,r,s,t,x,y,z,qw,qx,qy,qz";
// Written into every dataset: piles of another version are another generator's (its rules for
// when a drop has settled or is abandoned differ).
const char* const kGeneratorVersion = "simstack-generate-3";
namespace {

constexpr int kColumns = 15;

void writeAttr(H5::H5Object& obj, const std::string& name, double v) {
  obj.createAttribute(name, H5::PredType::NATIVE_DOUBLE, H5::DataSpace())
      .write(H5::PredType::NATIVE_DOUBLE, &v);
}
void writeAttr(H5::H5Object& obj, const std::string& name, int64_t v) {
  obj.createAttribute(name, H5::PredType::NATIVE_INT64, H5::DataSpace())
      .write(H5::PredType::NATIVE_INT64, &v);
}
void writeAttr(H5::H5Object& obj, const std::string& name, uint64_t v) {
  obj.createAttribute(name, H5::PredType::NATIVE_UINT64, H5::DataSpace())
      .write(H5::PredType::NATIVE_UINT64, &v);
}
void writeAttr(H5::H5Object& obj, const std::string& name, const std::string& v) {
  H5::StrType type(H5::PredType::C_S1, H5T_VARIABLE);
  obj.createAttribute(name, type, H5::DataSpace()).write(type, v);
}
/// The attribute, or std::runtime_error naming it when the file has none of that name.
H5::Attribute attribute(const H5::H5Object& obj, const std::string& name) {
  if (!obj.attrExists(name)) throw std::runtime_error("it has no attribute '" + name + "'");
  return obj.openAttribute(name);
}
template <typename T>
T readAttr(const H5::H5Object& obj, const std::string& name);
template <>
double readAttr<double>(const H5::H5Object& obj, const std::string& name) {
  double v = 0;
  attribute(obj, name).read(H5::PredType::NATIVE_DOUBLE, &v);
  return v;
}
template <>
int64_t readAttr<int64_t>(const H5::H5Object& obj, const std::string& name) {
  int64_t v = 0;
  attribute(obj, name).read(H5::PredType::NATIVE_INT64, &v);
  return v;
}
/// An unsigned attribute; one stored signed (an older file's seed) keeps its bits.
template <>
uint64_t readAttr<uint64_t>(const H5::H5Object& obj, const std::string& name) {
  const H5::Attribute attr = attribute(obj, name);
  if (attr.getIntType().getSign() == H5T_SGN_NONE) {
    uint64_t v = 0;
    attr.read(H5::PredType::NATIVE_UINT64, &v);
    return v;
  }
  int64_t v = 0;
  attr.read(H5::PredType::NATIVE_INT64, &v);
  return static_cast<uint64_t>(v);
}
template <>
std::string readAttr<std::string>(const H5::H5Object& obj, const std::string& name) {
  std::string v;
  H5::Attribute a = attribute(obj, name);
  a.read(a.getStrType(), v);
  return v;
}

H5::DataSet createArray(H5::H5File& file, const std::string& name, const H5::DataType& type,
                        std::vector<hsize_t> dims) {
  std::vector<hsize_t> chunk = dims;
  chunk[0] = 1;
  H5::DSetCreatPropList plist;
  plist.setChunk(static_cast<int>(chunk.size()), chunk.data());
  plist.setShuffle();
  plist.setDeflate(4);
  H5::DataSpace space(static_cast<int>(dims.size()), dims.data());
  return file.createDataSet(name, type, space, plist);
}

// Writes or reads the slab of scene `index` of a dataset whose first dimension is the scene.
void slab(const H5::DataSet& ds, int index, const H5::PredType& type, const void* data,
          bool write) {
  H5::DataSpace file_space = ds.getSpace();
  const int rank = file_space.getSimpleExtentNdims();
  std::vector<hsize_t> dims(rank), start(rank, 0), count;
  file_space.getSimpleExtentDims(dims.data());
  if (index < 0 || static_cast<hsize_t>(index) >= dims[0]) {
    throw std::out_of_range("scene index " + std::to_string(index) + " outside [0, " +
                            std::to_string(dims[0]) + ")");
  }
  start[0] = static_cast<hsize_t>(index);
  count = dims;
  count[0] = 1;
  file_space.selectHyperslab(H5S_SELECT_SET, count.data(), start.data());
  H5::DataSpace mem_space(rank, count.data());
  if (write) {
    ds.write(data, type, mem_space, file_space);
  } else {
    ds.read(const_cast<void*>(data), type, mem_space, file_space);
  }
}

std::string shapeText(const std::vector<hsize_t>& dims) {
  std::string s = "[";
  for (size_t i = 0; i < dims.size(); ++i) s += (i ? ", " : "") + std::to_string(dims[i]);
  return s + "]";
}

std::vector<hsize_t> shapeOf(const H5::DataSet& ds) {
  const H5::DataSpace space = ds.getSpace();
  std::vector<hsize_t> dims(static_cast<size_t>(std::max(0, space.getSimpleExtentNdims())));
  if (!dims.empty()) space.getSimpleExtentDims(dims.data());
  return dims;
}

hsize_t sceneCount(const H5::DataSet& tsdf) {
  const std::vector<hsize_t> dims = shapeOf(tsdf);
  if (dims.size() != 4) throw std::runtime_error("tsdf is not 4-dimensional");
  if (dims[0] < 1 || dims[0] > static_cast<hsize_t>(std::numeric_limits<int>::max()))
    throw std::runtime_error("tsdf holds " + std::to_string(dims[0]) + " scenes");
  return dims[0];
}

void expectShape(const H5::DataSet& ds, const char* name, const std::vector<hsize_t>& expected) {
  const std::vector<hsize_t> dims = shapeOf(ds);
  if (dims != expected)
    throw std::runtime_error(std::string(name) + " has shape " + shapeText(dims) + ", expected " +
                             shapeText(expected) + " from the scene count and the attributes");
}

void checkAttributes(const DatasetInfo& info) {
  if (info.resolution < 2 || info.resolution > 1024)
    throw std::runtime_error("attribute resolution " + std::to_string(info.resolution) +
                             " outside [2, 1024]");
  if (!(std::isfinite(info.extent_m) && info.extent_m > 0))
    throw std::runtime_error("attribute extent_m " + std::to_string(info.extent_m) +
                             " is not a positive length");
  if (!(std::isfinite(info.truncation_m) && info.truncation_m > 0))
    throw std::runtime_error("attribute truncation_m " + std::to_string(info.truncation_m) +
                             " is not a positive length");
  if (info.max_objects_per_scene < 0 || info.max_objects_per_scene > 10000)
    throw std::runtime_error("attribute max_objects_per_scene " +
                             std::to_string(info.max_objects_per_scene) + " outside [0, 10000]");
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (size_t i = 0; i < v.size(); ++i) s += (i ? "," : "") + v[i];
  return s;
}

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

}  // namespace

struct DatasetWriter::Impl {
  std::string path;
  DatasetInfo info;
  std::unique_ptr<H5::H5File> file;
  H5::DataSet tsdf, votes, labels, origin, count, objects;
};

DatasetWriter::DatasetWriter(const std::string& path, const DatasetInfo& info)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  impl_->info = info;
  if (info.num_scenes <= 0) throw std::invalid_argument("a dataset needs at least one scene");
  try {
    H5::Exception::dontPrint();
    impl_->file = std::make_unique<H5::H5File>(path, H5F_ACC_TRUNC);
    const hsize_t n = info.num_scenes, r = info.resolution, k = info.max_objects_per_scene;
    impl_->tsdf = createArray(*impl_->file, "tsdf", H5::PredType::NATIVE_FLOAT, {n, r, r, r});
    impl_->votes = createArray(*impl_->file, "votes", H5::PredType::NATIVE_FLOAT, {n, 3, r, r, r});
    impl_->labels = createArray(*impl_->file, "labels", H5::PredType::NATIVE_UINT8, {n, r, r, r});
    impl_->origin = createArray(*impl_->file, "grid_origin", H5::PredType::NATIVE_DOUBLE, {n, 3});
    impl_->count = createArray(*impl_->file, "num_objects", H5::PredType::NATIVE_INT32, {n});
    impl_->objects =
        createArray(*impl_->file, "objects", H5::PredType::NATIVE_DOUBLE, {n, k, kColumns});
    writeAttr(impl_->objects, "columns", std::string(kObjectColumns));
    H5::Group root = impl_->file->openGroup("/");
    writeAttr(root, "resolution", static_cast<int64_t>(info.resolution));
    writeAttr(root, "extent_m", info.extent_m);
    writeAttr(root, "voxel_size_m", info.extent_m / info.resolution);
    writeAttr(root, "truncation_m", info.truncation_m);
    writeAttr(root, "seed", static_cast<uint64_t>(info.seed));
    writeAttr(root, "min_objects", static_cast<int64_t>(info.min_objects));
    writeAttr(root, "max_objects", static_cast<int64_t>(info.max_objects));
    writeAttr(root, "max_objects_per_scene", static_cast<int64_t>(info.max_objects_per_scene));
    writeAttr(root, "generator_version", std::string(kGeneratorVersion));
    writeAttr(root, "mesh_names", join(info.mesh_names));
    writeAttr(root, "grid_axes", std::string("[z][y][x], table frame, z up from the table"));
  } catch (const H5::Exception& e) {
    throw std::runtime_error("cannot create dataset " + path + ": " + e.getDetailMsg());
  }
}

DatasetWriter::~DatasetWriter() = default;

void DatasetWriter::write(int index, const Scene& scene, const GroundTruthGrids& gt) {
  const DatasetInfo& info = impl_->info;
  if (gt.tsdf.spec.resolution != info.resolution)
    throw std::invalid_argument("ground truth resolution does not match the dataset");
  if (static_cast<int>(scene.objects.size()) > info.max_objects_per_scene) {
    throw std::invalid_argument("scene has " + std::to_string(scene.objects.size()) +
                                " objects, the dataset holds at most " +
                                std::to_string(info.max_objects_per_scene));
  }
  const int nv = gt.tsdf.spec.voxelCount();
  std::vector<float> votes(3 * static_cast<size_t>(nv));
  for (int i = 0; i < nv; ++i) {
    for (int c = 0; c < 3; ++c) votes[static_cast<size_t>(c) * nv + i] = gt.votes.data[i][c];
  }
  std::vector<double> objects(static_cast<size_t>(info.max_objects_per_scene) * kColumns, 0.0);
  for (size_t k = 0; k < scene.objects.size(); ++k) {
    const auto& o = scene.objects[k];
    double* row = &objects[k * kColumns];
    const bool sq = o.shape->kind() == ObjectShape::Kind::kSuperquadric;
    row[0] = sq ? 0.0 : 1.0;
    row[1] = o.shape->catalogueIndex();
    if (sq) {
      for (int i = 0; i < 3; ++i) {
        row[2 + i] = o.shape->superquadric().scale_m[i];
        row[5 + i] = o.shape->superquadric().exponents[i];
      }
    }
    const Vec3 t = o.T_table_object.translation();
    const Quat q(o.T_table_object.linear());
    for (int i = 0; i < 3; ++i) row[8 + i] = t[i];
    row[11] = q.w();
    row[12] = q.x();
    row[13] = q.y();
    row[14] = q.z();
  }
  const int32_t n = static_cast<int32_t>(scene.objects.size());
  Vec3 origin = gt.tsdf.spec.origin_table;
  try {
    slab(impl_->tsdf, index, H5::PredType::NATIVE_FLOAT, gt.tsdf.data.data(), true);
    slab(impl_->votes, index, H5::PredType::NATIVE_FLOAT, votes.data(), true);
    slab(impl_->labels, index, H5::PredType::NATIVE_UINT8, gt.labels.data.data(), true);
    slab(impl_->origin, index, H5::PredType::NATIVE_DOUBLE, origin.data(), true);
    slab(impl_->count, index, H5::PredType::NATIVE_INT32, &n, true);
    slab(impl_->objects, index, H5::PredType::NATIVE_DOUBLE, objects.data(), true);
  } catch (const H5::Exception& e) {
    throw std::runtime_error("cannot write scene " + std::to_string(index) + " to " + impl_->path +
                             ": " + e.getDetailMsg());
  }
}

struct DatasetReader::Impl {
  std::string path;
  DatasetInfo info;
  std::unique_ptr<H5::H5File> file;
  H5::DataSet tsdf, votes, labels, origin, count, objects;
  std::vector<std::shared_ptr<const ObjectShape>> catalogue;
  std::mutex mutex;  // one HDF5 read at a time (the trainer reads from two threads)
};

void refuseHeldOutDatasets(const std::vector<std::string>& paths, const std::string& use) {
  static const std::set<uint64_t> held_out{777, 778, 779, 780, 4242, 4243, 4244, 4245, 4246};
  for (const std::string& path : paths) {
    uint64_t seed = 0;
    try {
      H5::Exception::dontPrint();
      const H5::H5File file(path, H5F_ACC_RDONLY);
      seed = readAttr<uint64_t>(file.openGroup("/"), "seed");
    } catch (const H5::Exception&) {
      continue;  // not a dataset: the reader says so
    } catch (const std::runtime_error&) {
      continue;
    }
    if (held_out.count(seed))
      throw std::runtime_error(path + " holds held-out piles (seed " + std::to_string(seed) +
                               ", docs/results.md): " + use +
                               " piles of another seed, or pass --allow-held-out");
  }
}

DatasetReader::DatasetReader(const std::string& path, const std::string& mesh_dir)
    : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  // A file that cannot be opened says why (HDF5's own failure reads as a file that is not one).
  if (std::ifstream probe(path, std::ios::binary); !probe)
    throw std::runtime_error("cannot read dataset " + path + ": " + std::strerror(errno));
  try {
    H5::Exception::dontPrint();
    impl_->file = std::make_unique<H5::H5File>(path, H5F_ACC_RDONLY);
    H5::Group root = impl_->file->openGroup("/");
    DatasetInfo& info = impl_->info;
    info.resolution = static_cast<int>(readAttr<int64_t>(root, "resolution"));
    info.extent_m = readAttr<double>(root, "extent_m");
    info.truncation_m = readAttr<double>(root, "truncation_m");
    info.seed = readAttr<uint64_t>(root, "seed");
    info.min_objects = static_cast<int>(readAttr<int64_t>(root, "min_objects"));
    info.max_objects = static_cast<int>(readAttr<int64_t>(root, "max_objects"));
    info.max_objects_per_scene = static_cast<int>(readAttr<int64_t>(root, "max_objects_per_scene"));
    info.generator_version = readAttr<std::string>(root, "generator_version");
    info.mesh_names = split(readAttr<std::string>(root, "mesh_names"));
    const auto array = [&](const std::string& name) {
      if (H5Lexists(impl_->file->getId(), name.c_str(), H5P_DEFAULT) <= 0)
        throw std::runtime_error("it has no array '" + name + "'");
      return impl_->file->openDataSet(name);
    };
    impl_->tsdf = array("tsdf");
    impl_->votes = array("votes");
    impl_->labels = array("labels");
    impl_->origin = array("grid_origin");
    impl_->count = array("num_objects");
    impl_->objects = array("objects");
    checkAttributes(info);
    const hsize_t n = sceneCount(impl_->tsdf);
    const hsize_t r = info.resolution, k = info.max_objects_per_scene;
    // Every read fills a buffer sized from the attributes: a dataset of another shape would
    // overrun it.
    expectShape(impl_->tsdf, "tsdf", {n, r, r, r});
    expectShape(impl_->votes, "votes", {n, 3, r, r, r});
    expectShape(impl_->labels, "labels", {n, r, r, r});
    expectShape(impl_->origin, "grid_origin", {n, 3});
    expectShape(impl_->count, "num_objects", {n});
    expectShape(impl_->objects, "objects", {n, k, kColumns});
    info.num_scenes = static_cast<int>(n);
  } catch (const H5::Exception& e) {
    throw std::runtime_error("cannot read dataset " + path + ": " + e.getDetailMsg() +
                             " (not an HDF5 file of simstack_generate's, or cut short?)");
  } catch (const std::runtime_error& e) {
    throw std::runtime_error("cannot read dataset " + path + ": " + e.what());
  }
  if (!impl_->info.mesh_names.empty()) {
    if (mesh_dir.empty() && !proceduralCatalogue(impl_->info.mesh_names)) {
      throw std::runtime_error("dataset " + path +
                               " holds mesh objects (YCB piles): reading it needs the directory "
                               "of their meshes, which simstack_evaluate, simstack_train and "
                               "simstack_tune_hough take (--ycb DIR); the grasp evaluation takes "
                               "superquadric piles only");
    }
    impl_->catalogue = loadMeshCatalogue(mesh_dir, impl_->info.mesh_names);
  }
}

DatasetReader::~DatasetReader() = default;

const DatasetInfo& DatasetReader::info() const { return impl_->info; }

SceneRecord DatasetReader::readScene(int index) const {
  H5::Exception::dontPrint();  // per thread: a failed read is one exception, not a stack dump
  const DatasetInfo& info = impl_->info;
  SceneRecord rec;
  int32_t n = 0;
  Vec3 origin;
  std::vector<double> objects(static_cast<size_t>(info.max_objects_per_scene) * kColumns);
  std::unique_lock<std::mutex> lock(impl_->mutex);
  try {
    slab(impl_->count, index, H5::PredType::NATIVE_INT32, &n, false);
    slab(impl_->origin, index, H5::PredType::NATIVE_DOUBLE, origin.data(), false);
    slab(impl_->objects, index, H5::PredType::NATIVE_DOUBLE, objects.data(), false);
  } catch (const H5::Exception& e) {
    throw std::runtime_error("cannot read scene " + std::to_string(index) + " of " + impl_->path +
                             ": " + e.getDetailMsg());
  }
  if (n < 0 || n > info.max_objects_per_scene) {
    throw std::runtime_error(impl_->path + ": scene " + std::to_string(index) +
                             " has an invalid object count " + std::to_string(n));
  }
  rec.grid.origin_table = origin;
  rec.grid.resolution = info.resolution;
  rec.grid.voxel_size_m = info.extent_m / info.resolution;
  for (int k = 0; k < n; ++k) {
    const double* row = &objects[static_cast<size_t>(k) * kColumns];
    const std::string where =
        impl_->path + ": scene " + std::to_string(index) + ", object " + std::to_string(k);
    if (!std::all_of(row, row + kColumns, [](double v) { return std::isfinite(v); }))
      throw std::runtime_error(where + " holds a value that is not finite");
    SceneObject o;
    if (row[0] == 0.0) {
      if (!std::all_of(row + 2, row + 8, [](double v) { return v > 0.0; }))  // a1-a3, r s t
        throw std::runtime_error(where + ": a superquadric's semi-axes and exponents must be > 0");
      // An object of a pile fits its grid.
      if (!std::all_of(row + 2, row + 5, [&](double v) { return v <= info.extent_m; }))
        throw std::runtime_error(where + ": a semi-axis is longer than the grid's side " +
                                 std::to_string(info.extent_m) + " m");
      SuperquadricShape sq;
      sq.scale_m = Vec3(row[2], row[3], row[4]);
      sq.exponents = Vec3(row[5], row[6], row[7]);
      o.shape = ObjectShape::fromSuperquadric(sq);
    } else {
      const int c = static_cast<int>(row[1]);
      if (c < 0 || c >= static_cast<int>(impl_->catalogue.size())) {
        throw std::runtime_error(impl_->path + ": scene " + std::to_string(index) + " names mesh " +
                                 std::to_string(c) + " outside the catalogue");
      }
      o.shape = impl_->catalogue[c];
    }
    const Quat q(row[11], row[12], row[13], row[14]);
    if (std::abs(q.norm() - 1.0) > 1e-3)
      throw std::runtime_error(where + ": its orientation quaternion has norm " +
                               std::to_string(q.norm()) + ", not 1");
    const Vec3 centre(row[8], row[9], row[10]);
    const Vec3 lo = origin, hi = origin + Vec3::Constant(info.extent_m);
    const double outside = (lo - centre).cwiseMax(centre - hi).cwiseMax(0.0).norm();
    if (outside > info.extent_m)
      throw std::runtime_error(where + ": its centre lies " + std::to_string(outside) +
                               " m outside the scene's grid (of side " +
                               std::to_string(info.extent_m) + " m)");
    o.T_table_object = Transform::Identity();
    o.T_table_object.linear() = q.normalized().toRotationMatrix();
    o.T_table_object.translation() = centre;
    rec.scene.objects.push_back(o);
  }
  return rec;
}

SceneRecord DatasetReader::read(int index) const {
  SceneRecord rec = readScene(index);
  const int nv = rec.grid.voxelCount();
  rec.ground_truth.tsdf = Grid3<float>(rec.grid, 0.0f);
  rec.ground_truth.labels = Grid3<uint8_t>(rec.grid, 0);
  rec.ground_truth.votes = Grid3<Vec3f>(rec.grid, Vec3f::Zero());
  std::vector<float> votes(3 * static_cast<size_t>(nv));
  std::unique_lock<std::mutex> lock(impl_->mutex);
  try {
    slab(impl_->tsdf, index, H5::PredType::NATIVE_FLOAT, rec.ground_truth.tsdf.data.data(), false);
    slab(impl_->labels, index, H5::PredType::NATIVE_UINT8, rec.ground_truth.labels.data.data(),
         false);
    slab(impl_->votes, index, H5::PredType::NATIVE_FLOAT, votes.data(), false);
  } catch (const H5::Exception& e) {
    throw std::runtime_error("cannot read scene " + std::to_string(index) + " of " + impl_->path +
                             ": " + e.getDetailMsg());
  }
  lock.unlock();
  const auto finite = [](const std::vector<float>& v) {
    return std::all_of(v.begin(), v.end(), [](float x) { return std::isfinite(x); });
  };
  if (!finite(rec.ground_truth.tsdf.data) || !finite(votes))
    throw std::runtime_error(impl_->path + ": scene " + std::to_string(index) +
                             " holds tsdf or vote values that are not finite");
  for (int i = 0; i < nv; ++i) {
    rec.ground_truth.votes.data[i] =
        Vec3f(votes[i], votes[static_cast<size_t>(nv) + i], votes[2 * static_cast<size_t>(nv) + i]);
  }
  return rec;
}

namespace {

/// Whether two files hold the same piles: one seed, and the same first pile (the generator's
/// size range and object kinds are not among a file's attributes).
bool samePiles(const DatasetReader& a, const DatasetReader& b) {
  if (a.info().seed != b.info().seed || a.size() == 0 || b.size() == 0) return false;
  const Scene sa = a.readScene(0).scene, sb = b.readScene(0).scene;
  if (sa.objects.size() != sb.objects.size()) return false;
  for (size_t i = 0; i < sa.objects.size(); ++i)
    if (!sa.objects[i].T_table_object.isApprox(sb.objects[i].T_table_object, 1e-9)) return false;
  return true;
}

}  // namespace

DatasetMix::DatasetMix(const std::vector<std::string>& paths, const std::string& mesh_dir)
    : paths_(paths) {
  if (paths.empty()) throw std::invalid_argument("a dataset mix needs at least one file");
  for (const std::string& p : paths) {
    readers_.push_back(std::make_unique<DatasetReader>(p, mesh_dir));
    const DatasetInfo& a = readers_.front()->info();
    const DatasetInfo& b = readers_.back()->info();
    if (a.resolution != b.resolution || std::abs(a.extent_m - b.extent_m) > 1e-9 ||
        std::abs(a.truncation_m - b.truncation_m) > 1e-9) {
      std::ostringstream msg;
      msg << "dataset " << p << " has " << b.resolution << "^3 grids over " << b.extent_m
          << " m truncated at " << b.truncation_m << " m; " << paths.front() << " has "
          << a.resolution << "^3 over " << a.extent_m << " m truncated at " << a.truncation_m
          << " m: the files of one training must share their grids";
      throw std::runtime_error(msg.str());
    }
  }
  // Scene i depends on (seed, i) alone: two files of one seed and one generator share their
  // first piles, and the mix's validation piles (its last) would be trained on in the other.
  for (size_t a = 0; a < readers_.size(); ++a)
    for (size_t b = a + 1; b < readers_.size(); ++b)
      if (samePiles(*readers_[a], *readers_[b]))
        throw std::runtime_error(
            "datasets " + paths[a] + " and " + paths[b] + " hold the same piles (seed " +
            std::to_string(readers_[a]->info().seed) +
            ", the same first pile): the piles one validates on would be trained on in the "
            "other; generate one of them with another --seed");
  std::vector<int64_t> taken(readers_.size(), 0);
  int64_t total = 0;
  for (const auto& r : readers_) total += r->size();
  order_.reserve(static_cast<size_t>(total));
  for (int64_t i = 0; i < total; ++i) {
    int best = -1;
    for (int k = 0; k < static_cast<int>(readers_.size()); ++k) {
      const int64_t n = readers_[k]->size();
      if (taken[k] >= n) continue;
      // taken_k / n_k < taken_best / n_best, in integers
      if (best < 0 || taken[k] * readers_[best]->size() < taken[best] * n) best = k;
    }
    order_.emplace_back(best, static_cast<int>(taken[best]++));
  }
}

DatasetMix::~DatasetMix() = default;

std::string DatasetMix::name() const {
  std::string out;
  for (const std::string& p : paths_) out += (out.empty() ? "" : " + ") + p;
  return out;
}

SceneRecord DatasetMix::read(int index) const {
  const auto [k, i] = locate(index);
  return readers_[k]->read(i);
}

}  // namespace simstack
