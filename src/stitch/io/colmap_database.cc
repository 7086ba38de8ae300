#include "stitch/io/colmap_database.h"

#include <sqlite3.h>

#include <cstdint>
#include <filesystem>
#include <map>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "stitch/util/error.h"

namespace stitch {
namespace {

// COLMAP's schema (src/base/database.cc, version 3.8).
constexpr const char* kSchema = R"sql(
CREATE TABLE cameras (camera_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, model INTEGER NOT NULL,
  width INTEGER NOT NULL, height INTEGER NOT NULL, params BLOB, prior_focal_length INTEGER NOT NULL);
CREATE TABLE images (image_id INTEGER PRIMARY KEY AUTOINCREMENT NOT NULL, name TEXT NOT NULL UNIQUE,
  camera_id INTEGER NOT NULL, prior_qw REAL, prior_qx REAL, prior_qy REAL, prior_qz REAL, prior_tx REAL,
  prior_ty REAL, prior_tz REAL, CONSTRAINT image_id_check CHECK(image_id >= 0 and image_id < 2147483647),
  FOREIGN KEY(camera_id) REFERENCES cameras(camera_id));
CREATE UNIQUE INDEX index_name ON images(name);
CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
  data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE descriptors (image_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
  data BLOB, FOREIGN KEY(image_id) REFERENCES images(image_id) ON DELETE CASCADE);
CREATE TABLE matches (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL, cols INTEGER NOT NULL,
  data BLOB);
CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY NOT NULL, rows INTEGER NOT NULL,
  cols INTEGER NOT NULL, data BLOB, config INTEGER NOT NULL, F BLOB, E BLOB, H BLOB, qvec BLOB, tvec BLOB);
)sql";

constexpr int64_t kMaxImageId = 2147483647;  // COLMAP's pair id: image_id1 * kMaxImageId + image_id2
constexpr int kCalibrated = 2;               // TwoViewGeometry::CALIBRATED

class Database {
 public:
  explicit Database(const std::string& path) : path_(path) {
    if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr) != SQLITE_OK) {
      const std::string why = db_ ? sqlite3_errmsg(db_) : "out of memory";
      sqlite3_close(db_);
      throw Error(path + ": cannot create the database: " + why);
    }
  }
  ~Database() { sqlite3_close(db_); }
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  void Execute(const char* sql) {
    char* message = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &message) != SQLITE_OK) {
      const std::string why = message ? message : "unknown error";
      sqlite3_free(message);
      throw Error(path_ + ": " + why);
    }
  }

  // One prepared statement, bound and stepped per row.
  class Statement {
   public:
    Statement(Database* db, const char* sql) : db_(db) {
      if (sqlite3_prepare_v2(db->db_, sql, -1, &statement_, nullptr) != SQLITE_OK) db->Fail();
    }
    ~Statement() { sqlite3_finalize(statement_); }
    Statement(const Statement&) = delete;
    Statement& operator=(const Statement&) = delete;

    Statement& Int(int column, int64_t value) {
      Check(sqlite3_bind_int64(statement_, column, value));
      return *this;
    }
    Statement& Real(int column, double value) {
      Check(sqlite3_bind_double(statement_, column, value));
      return *this;
    }
    Statement& Text(int column, const std::string& value) {
      Check(sqlite3_bind_text(statement_, column, value.c_str(), static_cast<int>(value.size()), SQLITE_TRANSIENT));
      return *this;
    }
    Statement& Blob(int column, const void* data, size_t bytes) {
      Check(sqlite3_bind_blob(statement_, column, data, static_cast<int>(bytes), SQLITE_TRANSIENT));
      return *this;
    }
    void Run() {
      if (sqlite3_step(statement_) != SQLITE_DONE) db_->Fail();
      sqlite3_reset(statement_);
      sqlite3_clear_bindings(statement_);
    }

   private:
    void Check(int status) {
      if (status != SQLITE_OK) db_->Fail();
    }
    Database* db_;
    sqlite3_stmt* statement_ = nullptr;
  };

 private:
  [[noreturn]] void Fail() { throw Error(path_ + ": " + sqlite3_errmsg(db_)); }
  std::string path_;
  sqlite3* db_ = nullptr;
};

// The pinhole part of a camera, in COLMAP's pixel convention.
Eigen::Matrix3d ColmapK(const Camera& camera) {
  Eigen::Matrix3d k = camera.Intrinsics().K();
  k(0, 2) += kColmapHalfPixel;
  k(1, 2) += kColmapHalfPixel;
  return k;
}

}  // namespace

ColmapDatabaseSummary WriteColmapDatabase(const ColmapModel& model, const std::string& path) {
  if (std::filesystem::exists(path)) throw Error(path + " exists already; give a new one");
  ColmapDatabaseSummary summary;
  std::map<int, const ColmapImage*> image_of;
  for (const ColmapImage& image : model.images) {
    if (image.id <= 0 || image.id >= kMaxImageId) throw Error("COLMAP image id " + std::to_string(image.id));
    if (!model.cameras.count(image.camera_id)) {
      throw Error("COLMAP image " + std::to_string(image.id) + ": no camera " + std::to_string(image.camera_id));
    }
    image_of[image.id] = &image;
  }
  // The matches of every pair of images: features of one point, as (image id 1 < image id 2).
  std::map<std::pair<int, int>, std::vector<uint32_t>> pair_matches;
  for (const ColmapPoint& point : model.points) {
    for (size_t a = 0; a < point.track.size(); ++a) {
      for (size_t b = a + 1; b < point.track.size(); ++b) {
        auto first = point.track[a], second = point.track[b];
        if (first.first == second.first) continue;
        if (first.first > second.first) std::swap(first, second);
        std::vector<uint32_t>& rows = pair_matches[{first.first, second.first}];
        rows.push_back(static_cast<uint32_t>(first.second));
        rows.push_back(static_cast<uint32_t>(second.second));
      }
    }
  }

  bool created = false;
  try {
    Database db(path);
    created = true;
    db.Execute(kSchema);
    db.Execute("BEGIN TRANSACTION");
    {
      Database::Statement insert(&db,
                                 "INSERT INTO cameras (camera_id, model, width, height, params, prior_focal_length) "
                                 "VALUES (?, ?, ?, ?, ?, 1)");
      for (const auto& [id, camera] : model.cameras) {
        const ColmapCameraModel colmap = ColmapCameraModelOf(camera);
        insert.Int(1, id).Int(2, colmap.id).Int(3, camera.width()).Int(4, camera.height());
        insert.Blob(5, colmap.params.data(), colmap.params.size() * sizeof(double)).Run();
        ++summary.cameras;
      }
    }
    {
      Database::Statement insert(&db,
                                 "INSERT INTO images (image_id, name, camera_id, prior_qw, prior_qx, prior_qy, "
                                 "prior_qz, prior_tx, prior_ty, prior_tz) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
      Database::Statement keypoints(&db, "INSERT INTO keypoints (image_id, rows, cols, data) VALUES (?, ?, 2, ?)");
      for (const ColmapImage& image : model.images) {
        const Eigen::Quaterniond& q = image.cam_from_world.rotation;
        const Eigen::Vector3d& t = image.cam_from_world.translation;
        insert.Int(1, image.id).Text(2, image.name).Int(3, image.camera_id);
        insert.Real(4, q.w()).Real(5, q.x()).Real(6, q.y()).Real(7, q.z());
        insert.Real(8, t.x()).Real(9, t.y()).Real(10, t.z()).Run();
        std::vector<float> xy;
        xy.reserve(2 * image.features.size());
        for (const Eigen::Vector2d& f : image.features) {
          xy.push_back(static_cast<float>(f.x() + kColmapHalfPixel));
          xy.push_back(static_cast<float>(f.y() + kColmapHalfPixel));
        }
        keypoints.Int(1, image.id).Int(2, static_cast<int64_t>(image.features.size()));
        keypoints.Blob(3, xy.data(), xy.size() * sizeof(float)).Run();
        ++summary.images;
        summary.keypoints += static_cast<int>(image.features.size());
      }
    }
    {
      Database::Statement matches(&db, "INSERT INTO matches (pair_id, rows, cols, data) VALUES (?, ?, 2, ?)");
      Database::Statement geometry(&db,
                                   "INSERT INTO two_view_geometries (pair_id, rows, cols, data, config, F, E, H, qvec, "
                                   "tvec) VALUES (?, ?, 2, ?, ?, ?, ?, ?, ?, ?)");
      for (const auto& [pair, rows] : pair_matches) {
        const ColmapImage& first = *image_of.at(pair.first);
        const ColmapImage& second = *image_of.at(pair.second);
        const int64_t pair_id = pair.first * kMaxImageId + pair.second;
        const int64_t count = static_cast<int64_t>(rows.size() / 2);
        const size_t bytes = rows.size() * sizeof(uint32_t);
        matches.Int(1, pair_id).Int(2, count).Blob(3, rows.data(), bytes).Run();
        // The pair's geometry as the map has it: x2' E x1 = 0 with cam2_from_cam1 = (R, t).
        const Rigid3d relative = second.cam_from_world * first.cam_from_world.Inverse();
        const double baseline = relative.translation.norm();
        const Eigen::Vector3d direction =
            baseline > 0 ? Eigen::Vector3d(relative.translation / baseline) : Eigen::Vector3d::Zero();
        const Eigen::Matrix3d essential = Rigid3d(relative.rotation, direction).EssentialMatrix();
        const Eigen::Matrix3d fundamental = ColmapK(model.cameras.at(second.camera_id)).inverse().transpose() *
                                            essential * ColmapK(model.cameras.at(first.camera_id)).inverse();
        const Eigen::Matrix3d homography = Eigen::Matrix3d::Zero();  // not estimated: the map is no plane
        const Eigen::Vector4d qvec(relative.rotation.w(), relative.rotation.x(), relative.rotation.y(),
                                   relative.rotation.z());
        const Eigen::Vector3d tvec = direction;
        geometry.Int(1, pair_id).Int(2, count).Blob(3, rows.data(), bytes).Int(4, kCalibrated);
        geometry.Blob(5, fundamental.data(), 9 * sizeof(double)).Blob(6, essential.data(), 9 * sizeof(double));
        geometry.Blob(7, homography.data(), 9 * sizeof(double)).Blob(8, qvec.data(), 4 * sizeof(double));
        geometry.Blob(9, tvec.data(), 3 * sizeof(double)).Run();
        ++summary.image_pairs;
        summary.matches += static_cast<int>(count);
      }
    }
    db.Execute("COMMIT");
  } catch (...) {
    if (created) std::filesystem::remove(path);  // never a half-written project
    throw;
  }
  return summary;
}

}  // namespace stitch
