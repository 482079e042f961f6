#pragma once
// Reads the SIFT descriptors of every image in a COLMAP database (the SQLite
// file feature_extractor writes), for the cameras stage's own matching
// (pipeline/inputs/descriptor_matching.hpp). Read-only; nothing else in the
// database is touched.
//
// COLMAP's layout: table `images` (image_id, name, ...) and table
// `descriptors` (image_id, rows, cols, data), data being rows x cols uint8 in
// row-major order, one descriptor a row (cols = 128 for SIFT). An image
// without a descriptors row has none. A blob whose size is not rows * cols,
// a column count other than 128, or a missing table is an error naming the
// database and the image.
#include <sqlite3.h>

#include <Eigen/Core>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

// One descriptor a row, as COLMAP stores them (each row's L2 norm about 512).
using SiftDescriptors = Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 128, Eigen::RowMajor>;

struct ColmapDatabaseImage {
  std::int64_t id = 0;
  std::string name;
  SiftDescriptors descriptors;
};

namespace colmap_database_detail {

struct CloseDatabase {
  void operator()(sqlite3* db) const { sqlite3_close(db); }
};
struct FinalizeStatement {
  void operator()(sqlite3_stmt* s) const { sqlite3_finalize(s); }
};
using Database = std::unique_ptr<sqlite3, CloseDatabase>;
using Statement = std::unique_ptr<sqlite3_stmt, FinalizeStatement>;

inline Statement prepare(sqlite3* db, const std::string& path, const char* sql) {
  sqlite3_stmt* s = nullptr;
  const int rc = sqlite3_prepare_v2(db, sql, -1, &s, nullptr);
  Statement owned(s);
  ensure(rc == SQLITE_OK, "COLMAP database ", path, ": ", sqlite3_errmsg(db), " (in \"", sql, "\")");
  return owned;
}

}  // namespace colmap_database_detail

// Every image of the database in image_id order, with its descriptors.
inline std::vector<ColmapDatabaseImage> read_colmap_database_descriptors(const std::string& path) {
  namespace d = colmap_database_detail;
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &raw, SQLITE_OPEN_READONLY, nullptr);
  d::Database db(raw);
  ensure(rc == SQLITE_OK, "COLMAP database ", path, ": cannot open: ", raw ? sqlite3_errmsg(raw) : "out of memory");

  std::vector<ColmapDatabaseImage> images;
  {
    d::Statement s = d::prepare(db.get(), path, "SELECT image_id, name FROM images ORDER BY image_id");
    int step;
    while ((step = sqlite3_step(s.get())) == SQLITE_ROW) {
      ColmapDatabaseImage im;
      im.id = sqlite3_column_int64(s.get(), 0);
      const unsigned char* name = sqlite3_column_text(s.get(), 1);
      ensure(name != nullptr, "COLMAP database ", path, ": image ", im.id, " has no name");
      im.name = reinterpret_cast<const char*>(name);
      images.push_back(std::move(im));
    }
    ensure(step == SQLITE_DONE, "COLMAP database ", path, ": reading images: ", sqlite3_errmsg(db.get()));
  }

  d::Statement s = d::prepare(db.get(), path, "SELECT rows, cols, data FROM descriptors WHERE image_id = ?");
  for (ColmapDatabaseImage& im : images) {
    sqlite3_reset(s.get());
    sqlite3_bind_int64(s.get(), 1, im.id);
    const int step = sqlite3_step(s.get());
    if (step == SQLITE_DONE) continue;  // no descriptors row: no features
    ensure(step == SQLITE_ROW, "COLMAP database ", path, ": reading descriptors of ", im.name, ": ",
           sqlite3_errmsg(db.get()));
    const std::int64_t rows = sqlite3_column_int64(s.get(), 0), cols = sqlite3_column_int64(s.get(), 1);
    const void* data = sqlite3_column_blob(s.get(), 2);
    const std::int64_t bytes = sqlite3_column_bytes(s.get(), 2);
    ensure(rows >= 0 && (rows == 0 || cols == 128), "COLMAP database ", path, ": image ", im.name, " has ", rows,
           " descriptors of ", cols, " bytes; SIFT's have 128");
    ensure(bytes == rows * cols && (rows == 0 || data != nullptr), "COLMAP database ", path, ": image ", im.name,
           ": descriptor blob of ", bytes, " bytes, expected ", rows, " x ", cols);
    im.descriptors.resize(Eigen::Index(rows), 128);
    if (rows > 0) std::memcpy(im.descriptors.data(), data, std::size_t(bytes));
  }
  return images;
}

}  // namespace orbitforge
