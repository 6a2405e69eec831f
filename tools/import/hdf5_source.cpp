// HDF5 datasets through Debian's libhdf5 (C API): the dataset given by its path, 1-D (samples)
// or 2-D (samples, channels), of any integer or floating type (HDF5 converts to double on
// read). Read by hyperslab, a window at a time, so a long record is never held in memory.
#include <hdf5.h>

#include <string>
#include <vector>

#include "import_error.hpp"
#include "record_source.hpp"

namespace tipforce::import {
namespace {

// The object-info calls changed in HDF5 1.12 (Debian 12 ships 1.10, Debian 13 1.14).
#if H5_VERSION_GE(1, 12, 0)
using ObjectInfo = H5O_info2_t;
herr_t object_info(hid_t file, const char* name, ObjectInfo* info) {
  return H5Oget_info_by_name3(file, name, info, H5O_INFO_BASIC, H5P_DEFAULT);
}
herr_t visit_objects(hid_t file, H5O_iterate2_t f, void* data) {
  return H5Ovisit3(file, H5_INDEX_NAME, H5_ITER_NATIVE, f, data, H5O_INFO_BASIC);
}
#else
using ObjectInfo = H5O_info_t;
herr_t object_info(hid_t file, const char* name, ObjectInfo* info) {
  return H5Oget_info_by_name2(file, name, info, H5O_INFO_BASIC, H5P_DEFAULT);
}
herr_t visit_objects(hid_t file, H5O_iterate_t f, void* data) {
  return H5Ovisit2(file, H5_INDEX_NAME, H5_ITER_NATIVE, f, data, H5O_INFO_BASIC);
}
#endif

// HDF5 prints its error stack to stderr by default; while one of our calls runs, that is turned
// off and the stack is read into our message instead. Restored on scope exit, so a program that
// embeds this code keeps its own HDF5 error handling.
class QuietErrors {
 public:
  QuietErrors() {
    H5Eget_auto2(H5E_DEFAULT, &func_, &data_);
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  }
  ~QuietErrors() { H5Eset_auto2(H5E_DEFAULT, func_, data_); }
  QuietErrors(const QuietErrors&) = delete;
  QuietErrors& operator=(const QuietErrors&) = delete;

 private:
  H5E_auto2_t func_ = nullptr;
  void* data_ = nullptr;
};

// The innermost messages of the current HDF5 error stack, e.g. "truncated file: eof = 1024 ...".
std::string hdf5_reason() {
  std::vector<std::string> msgs;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_DOWNWARD,
      [](unsigned, const H5E_error2_t* e, void* out) -> herr_t {
        if (e->desc && *e->desc) static_cast<std::vector<std::string>*>(out)->push_back(e->desc);
        return 0;
      },
      &msgs);
  H5Eclear2(H5E_DEFAULT);
  std::string s;
  for (std::size_t i = 0; i < msgs.size() && i < 3; ++i) s += (i ? "; " : "") + msgs[msgs.size() - 1 - i];
  return s.empty() ? "no reason given" : s;
}

// An hid_t closed by its own close function on scope exit.
class Handle {
 public:
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  ~Handle() {
    if (id_ >= 0) close_(id_);
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  Handle(Handle&& o) noexcept : id_(o.id_), close_(o.close_) { o.id_ = -1; }
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      if (id_ >= 0) close_(id_);
      id_ = o.id_;
      close_ = o.close_;
      o.id_ = -1;
    }
    return *this;
  }
  hid_t get() const { return id_; }
  bool ok() const { return id_ >= 0; }

 private:
  hid_t id_;
  herr_t (*close_)(hid_t);
};

// Up to 20 dataset paths in the file, for the message when the one asked for is not there.
std::string list_datasets(hid_t file) {
  std::vector<std::string> names;
  visit_objects(
      file,
      [](hid_t, const char* name, const ObjectInfo* info, void* out) -> herr_t {
        auto* v = static_cast<std::vector<std::string>*>(out);
        if (info->type == H5O_TYPE_DATASET) v->push_back(std::string("/") + name);
        return v->size() >= 20 ? 1 : 0;
      },
      &names);
  H5Eclear2(H5E_DEFAULT);
  if (names.empty()) return "the file holds no dataset";
  std::string s = "datasets in the file:";
  for (const auto& n : names) s += " " + n;
  if (names.size() >= 20) s += " ...";
  return s;
}

class Hdf5Table : public RecordSource {
 public:
  Hdf5Table(const std::string& path, const std::string& dataset)
      : path_(path), dataset_(dataset), file_(-1, H5Fclose), set_(-1, H5Dclose), space_(-1, H5Sclose) {
    QuietErrors quiet;
    if (dataset.empty()) throw ImportError(path + ": an HDF5 file needs --dataset PATH (the dataset in the file)");
    const htri_t is = H5Fis_hdf5(path.c_str());
    if (is <= 0) {
      const std::string why = hdf5_reason();
      throw ImportError(path + ": not an HDF5 file, or truncated or damaged (" + why + ")");
    }
    file_ = Handle(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
    if (!file_.ok()) throw ImportError(path + ": cannot open as HDF5 (truncated or damaged?): " + hdf5_reason());
    // Walk the path one link at a time: H5Lexists fails, rather than answering no, when a
    // group on the way is missing.
    std::string partial;
    std::size_t pos = dataset[0] == '/' ? 1 : 0;
    while (pos <= dataset.size()) {
      const std::size_t slash = dataset.find('/', pos);
      partial = dataset.substr(0, slash == std::string::npos ? std::string::npos : slash);
      if (!partial.empty() && partial != "/" && H5Lexists(file_.get(), partial.c_str(), H5P_DEFAULT) <= 0) {
        H5Eclear2(H5E_DEFAULT);
        throw ImportError(path + ": no dataset " + dataset + " (" + partial + " does not exist; " +
                          list_datasets(file_.get()) + ")");
      }
      if (slash == std::string::npos) break;
      pos = slash + 1;
    }
    ObjectInfo info{};
    if (object_info(file_.get(), dataset.c_str(), &info) < 0 ||
        info.type != H5O_TYPE_DATASET)
      throw ImportError(path + ": " + dataset + " is not a dataset (a group?); " + list_datasets(file_.get()));
    set_ = Handle(H5Dopen2(file_.get(), dataset.c_str(), H5P_DEFAULT), H5Dclose);
    if (!set_.ok()) throw ImportError(path + ": cannot open dataset " + dataset + ": " + hdf5_reason());
    Handle type(H5Dget_type(set_.get()), H5Tclose);
    const H5T_class_t cls = H5Tget_class(type.get());
    if (cls != H5T_INTEGER && cls != H5T_FLOAT)
      throw ImportError(path + ": dataset " + dataset + " holds " + class_name(cls) +
                        ", not numbers (an integer or floating-point dataset is needed)");
    type_ = std::string(cls == H5T_INTEGER ? "int" : "float") + std::to_string(8 * H5Tget_size(type.get()));
    space_ = Handle(H5Dget_space(set_.get()), H5Sclose);
    const int rank = H5Sget_simple_extent_ndims(space_.get());
    if (rank < 1 || rank > 2)
      throw ImportError(path + ": dataset " + dataset + " has " + std::to_string(rank) +
                        " dimensions; a 1-D (samples) or 2-D (samples, channels) dataset is needed");
    hsize_t dims[2] = {0, 1};
    H5Sget_simple_extent_dims(space_.get(), dims, nullptr);
    rank_ = rank;
    rows_ = static_cast<std::int64_t>(dims[0]);
    columns_ = rank == 2 ? static_cast<int>(dims[1]) : 1;
    if (rows_ == 0) throw ImportError(path + ": dataset " + dataset + " is empty");
  }

  std::int64_t rows() const override { return rows_; }
  int columns() const override { return columns_; }
  void read(int column, std::int64_t begin, std::int64_t n, double* out) override {
    QuietErrors quiet;
    hsize_t start[2] = {static_cast<hsize_t>(begin), static_cast<hsize_t>(column)};
    hsize_t count[2] = {static_cast<hsize_t>(n), 1};
    if (H5Sselect_hyperslab(space_.get(), H5S_SELECT_SET, start, nullptr, count, nullptr) < 0)
      throw ImportError(path_ + ": " + dataset_ + ": cannot select samples " + std::to_string(begin) + "+" +
                        std::to_string(n) + ": " + hdf5_reason());
    Handle memory(H5Screate_simple(1, count, nullptr), H5Sclose);
    if (H5Dread(set_.get(), H5T_NATIVE_DOUBLE, memory.get(), space_.get(), H5P_DEFAULT, out) < 0)
      throw ImportError(path_ + ": reading " + dataset_ + " samples " + std::to_string(begin) + "+" + std::to_string(n) +
                        " failed (truncated or damaged file?): " + hdf5_reason());
  }
  std::string describe() const override {
    return path_ + ":" + dataset_ + " (hdf5, " + type_ + ", " + std::to_string(rank_) + "-D)";
  }

 private:
  static std::string class_name(H5T_class_t c) {
    switch (c) {
      case H5T_STRING: return "strings";
      case H5T_COMPOUND: return "compound records";
      case H5T_BITFIELD: return "bit fields";
      case H5T_OPAQUE: return "opaque data";
      case H5T_REFERENCE: return "references";
      case H5T_ENUM: return "enumerations";
      case H5T_VLEN: return "variable-length data";
      case H5T_ARRAY: return "arrays";
      default: return "a non-numeric type";
    }
  }

  std::string path_, dataset_, type_;
  Handle file_, set_, space_;
  int rank_ = 1;
  std::int64_t rows_ = 0;
  int columns_ = 1;
};

}  // namespace

std::unique_ptr<RecordSource> open_hdf5(const RecordSpec& spec) {
  return std::make_unique<Hdf5Table>(spec.path, spec.dataset);
}

}  // namespace tipforce::import
