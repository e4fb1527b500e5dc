#include "simstack/offline/training/cvae_trainer.h"

#include <ATen/CPUGeneratorImpl.h>
#include <fcntl.h>
#include <omp.h>
#include <sys/file.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <numeric>
#include <optional>
#include <set>
#include <sstream>
#include <thread>
#include <tuple>

#include "simstack/io/config_fields.h"
#include "simstack/io/staged_output.h"
#include "simstack/io/yaml_file.h"
#include "simstack/model/cvae.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/eval/occupancy.h"
#include "simstack/offline/training/cvae_losses.h"
#include "simstack/offline/training/model_writer.h"
#include "simstack/offline/training/training_sample.h"
#include "simstack/seeds.h"

namespace fs = std::filesystem;

namespace simstack {
namespace {

uint64_t mix(uint64_t a, uint64_t b) {
  return splitMix64(a * 0x9E3779B97F4A7C15ull + b + 0x632BE59BD9B4E019ull);
}

std::vector<float> values(const torch::Tensor& t) {
  const torch::Tensor c = t.contiguous();
  return std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
}

/// std::runtime_error when the dataset's grids are not the model's (`model_name` in the message).
void checkDatasetFitsModel(const DatasetInfo& info, const CvaeConfig& model,
                           const std::string& dataset_path, const std::string& model_name) {
  if (info.resolution != model.resolution || std::abs(info.extent_m - model.extent_m) > 1e-9) {
    throw std::runtime_error("dataset " + dataset_path + " has " + std::to_string(info.resolution) +
                             "^3 grids over " + std::to_string(info.extent_m) + " m, " +
                             model_name + " wants " + std::to_string(model.resolution) +
                             "^3 over " + std::to_string(model.extent_m) + " m");
  }
  if (std::abs(info.truncation_m - model.truncation_m()) > 1e-9) {
    throw std::runtime_error("dataset " + dataset_path + " is truncated at " +
                             std::to_string(info.truncation_m) + " m, " + model_name + " at " +
                             std::to_string(model.truncation_m()) + " m");
  }
}

struct Batch {
  torch::Tensor partial, tsdf, votes, vote_weight;  ///< vote_weight undefined when not used
};

Batch toBatch(const std::vector<TrainingSample>& samples, int r) {
  const int64_t b = static_cast<int64_t>(samples.size());
  Batch batch;
  batch.partial = torch::empty({b, 2, r, r, r});
  batch.tsdf = torch::empty({b, 1, r, r, r});
  batch.votes = torch::empty({b, 3, r, r, r});
  if (!samples.empty() && !samples.front().vote_weight.empty())
    batch.vote_weight = torch::empty({b, 1, r, r, r});
  for (int64_t i = 0; i < b; ++i) {
    std::copy(samples[i].partial.begin(), samples[i].partial.end(),
              batch.partial[i].data_ptr<float>());
    std::copy(samples[i].tsdf.begin(), samples[i].tsdf.end(), batch.tsdf[i].data_ptr<float>());
    std::copy(samples[i].votes.begin(), samples[i].votes.end(), batch.votes[i].data_ptr<float>());
    if (batch.vote_weight.defined())
      std::copy(samples[i].vote_weight.begin(), samples[i].vote_weight.end(),
                batch.vote_weight[i].data_ptr<float>());
  }
  return batch;
}

/// Training batches made by a worker thread ahead of the optimiser. Sample (step, i) depends
/// only on the seed, so a resumed run sees the data an uninterrupted one would have.
class BatchQueue {
 public:
  BatchQueue(const TrainConfig& tc, const TrainingSampleBuilder& builder, const DatasetMix& data,
             int train_scenes, int resolution, int64_t start)
      : worker_([=, &builder, &data] {
          omp_set_num_threads(1);
          for (int64_t step = start; step < tc.steps; ++step) {
            std::vector<TrainingSample> samples;
            Batch batch;
            try {  // nothing may leave the thread: an error goes to next() as a message
              for (int i = 0; i < tc.batch_size; ++i) {
                std::mt19937_64 rng(mix(tc.seed, static_cast<uint64_t>(step) * 1024 + i));
                std::uniform_int_distribution<int> pick(0, train_scenes - 1);
                samples.push_back(builder.build(data.read(pick(rng)), rng));
              }
              batch = toBatch(samples, resolution);
            } catch (const std::exception& e) {
              std::lock_guard<std::mutex> lock(mutex_);
              error_ = e.what();
              cv_.notify_all();
              return;
            }
            std::unique_lock<std::mutex> lock(mutex_);
            cv_.wait(lock, [&] { return queue_.size() < 3 || stop_; });
            if (stop_) return;
            queue_.push_back(std::move(batch));
            cv_.notify_all();
          }
        }) {}
  ~BatchQueue() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_ = true;
    }
    cv_.notify_all();
    worker_.join();
  }
  /// The next batch; throws std::runtime_error with the worker's message when it failed.
  Batch next() {
    std::unique_lock<std::mutex> lock(mutex_);
    cv_.wait(lock, [&] { return !queue_.empty() || !error_.empty(); });
    if (queue_.empty()) throw std::runtime_error(error_);
    Batch batch = std::move(queue_.front());
    queue_.pop_front();
    cv_.notify_all();
    return batch;
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<Batch> queue_;
  std::string error_;
  bool stop_ = false;
  std::thread worker_;  // last: starts after the members it uses
};

/// One step's losses, in train_log.csv's column order.
struct LossRow {
  double total = 0.0, tsdf = 0.0, partial = 0.0, votes = 0.0, mmd = 0.0, occupancy = 0.0, iou = 0.0;
  /// The fields in the log's column order.
  std::array<double*, 7> fields() {
    return {&total, &tsdf, &partial, &votes, &mmd, &occupancy, &iou};
  }
  std::array<double, 7> values() const {
    return {total, tsdf, partial, votes, mmd, occupancy, iou};
  }
};

/// train_log.csv: losses every 10 steps, validation figures at validation steps.
class TrainingLog {
 public:
  static constexpr const char* kHeader =
      "step,total,tsdf,partial,votes,mmd,occupancy,iou,samples_per_s,validation_iou,"
      "validation_bce,validation_disagreement,posterior_mu_rms,posterior_sigma,"
      "validation_posterior_iou,validation_iou_se,validation_single_iou,validation_best_iou,"
      "validation_disagreement_seen,validation_disagreement_unseen,validation_unseen_share";

  /// `append`: a resumed run, which keeps the rows up to its checkpoint's `step` (those a run
  /// killed after its last checkpoint wrote are trained again, and logged once).
  TrainingLog(const fs::path& path, bool append, int64_t step) : path_(path) {
    if (append) keepRowsThrough(step);
    log_.open(path.string(), append ? std::ios::app : std::ios::trunc);
    if (!log_) throw std::runtime_error("cannot write " + path.string());
    log_.seekp(0, std::ios::end);
    if (log_.tellp() == 0) {  // a new log (also when a finished model is trained further)
      log_ << kHeader << "\n";
    } else {
      std::ifstream previous(path.string());
      std::string header;
      std::getline(previous, header);
      if (!header.empty() && header.back() == '\r') header.pop_back();
      if (header != kHeader)
        throw std::runtime_error(
            path.string() + " has other columns than this trainer writes; move it aside to resume");
    }
  }
  void write(int64_t step, const LossRow& losses, const TrainingReport& report, bool validated,
             bool posterior_measured) {
    log_ << step;
    for (double v : losses.values()) log_ << "," << v;
    log_ << "," << report.samples_per_second;
    if (validated) {
      log_ << "," << report.validation_iou << "," << report.validation_bce << ","
           << report.validation_disagreement << ",";
      if (posterior_measured) {
        log_ << report.posterior_mu_rms << "," << report.posterior_sigma;
      } else {
        log_ << ",";  // FC baseline: no posterior
      }
      log_ << ",";
      if (std::isfinite(report.validation_posterior_iou)) log_ << report.validation_posterior_iou;
      log_ << "," << report.validation_iou_se << "," << report.validation_single_iou << ","
           << report.validation_best_iou << "," << report.validation_disagreement_seen << ","
           << report.validation_disagreement_unseen << "," << report.validation_unseen_share;
    }
    log_ << std::endl;  // each row on disk at once: a long run is followed with tail -f
    check();
  }
  void flush() {
    log_.flush();
    check();
  }
  /// A row that cannot be written (a full disk) stops the run: a log with rows missing would
  /// pass for a whole one. Thrown before the checkpoint is written, so that --resume finds the
  /// log and the last checkpoint in step.
  void check() const {
    if (!log_)
      throw std::runtime_error("cannot write " + path_.string() + " (" + std::strerror(errno) +
                               "): the run stops; its last checkpoint, if it has one, is kept "
                               "for --resume once the file can be written");
  }
  /// The losses and pace of the last logged step (a resumed run that had nothing left to do).
  bool lastRow(LossRow* losses, double* samples_per_second) const {
    std::ifstream previous(path_.string());
    std::string line, last;
    while (std::getline(previous, line))
      if (!line.empty() && std::isdigit(static_cast<unsigned char>(line[0]))) last = line;
    LossRow& l = *losses;
    return std::sscanf(last.c_str(), "%*[^,],%lf,%lf,%lf,%lf,%lf,%lf,%lf,%lf", &l.total, &l.tsdf,
                       &l.partial, &l.votes, &l.mmd, &l.occupancy, &l.iou, samples_per_second) == 8;
  }

 private:
  void keepRowsThrough(int64_t step) const {
    std::ifstream previous(path_.string());
    if (!previous) return;
    const fs::path kept = path_.string() + ".tmp";
    {
      std::ofstream out(kept.string(), std::ios::trunc);
      std::string line;
      while (std::getline(previous, line)) {
        const bool row = !line.empty() && std::isdigit(static_cast<unsigned char>(line[0]));
        if (!row || std::stoll(line) <= step) out << line << "\n";
      }
      if (!out) throw std::runtime_error("cannot write " + kept.string());
    }
    fs::rename(kept, path_);
  }

  fs::path path_;
  std::ofstream log_;
};

/// Running means over the last 50 steps of the losses and of the encoder's posterior on the
/// training batches (train mode; in eval mode BatchNorm's running statistics give other codes).
struct RecentSteps {
  std::deque<LossRow> losses;
  std::deque<std::array<double, 2>> posterior;  ///< mean square of mu, mean sigma

  void add(const CvaeLosses& l, const CvaeOutput& o, TrainingReport* report) {
    LossRow row;
    row.total = l.total.item<double>();
    row.tsdf = l.tsdf.item<double>();
    row.partial = l.partial.item<double>();
    row.votes = l.votes.item<double>();
    row.mmd = l.mmd.item<double>();
    row.occupancy = l.occupancy.item<double>();
    row.iou = l.iou.item<double>();
    losses.push_back(row);
    if (losses.size() > 50) losses.pop_front();
    if (!o.mu.defined()) return;
    torch::NoGradGuard no_grad;
    posterior.push_back(
        {o.mu.pow(2).mean().item<double>(), torch::exp(0.5 * o.logvar).mean().item<double>()});
    if (posterior.size() > 50) posterior.pop_front();
    double mu_sq = 0.0, sigma = 0.0;
    for (const auto& p : posterior) {
      mu_sq += p[0] / posterior.size();
      sigma += p[1] / posterior.size();
    }
    report->posterior_mu_rms = std::sqrt(mu_sq);
    report->posterior_sigma = sigma;
  }
  void meanInto(TrainingReport* report) const {
    if (losses.empty()) return;
    LossRow mean;
    for (const LossRow& a : losses) {
      const std::array<double, 7> v = a.values();
      const std::array<double*, 7> m = mean.fields();
      for (size_t i = 0; i < v.size(); ++i) *m[i] += v[i] / losses.size();
    }
    report->total = mean.total;
    report->tsdf = mean.tsdf;
    report->partial = mean.partial;
    report->votes = mean.votes;
    report->mmd = mean.mmd;
    report->occupancy = mean.occupancy;
    report->iou = mean.iou;
  }
};

// The card's settings read with the model (perception_config.h): a model with a latent code is
// sampled three times. A warm start keeps its parent's Hough setting (tuned for the nearest
// network there is); otherwise the default applies until simstack_tune_hough chooses one.
std::string cardPerceptionSection(const std::string& init_from, bool latent) {
  YAML::Node hough;  // stays Null unless the parent's card has a hough: map
  std::string parent_card = init_from.empty() ? "" : modelCardPath(init_from);
  // A run's checkpoint has no card of its own: its run's model card holds the setting.
  if (!parent_card.empty() && !fs::exists(parent_card) &&
      fs::path(init_from).filename() == "checkpoint.pt")
    parent_card = (fs::path(init_from).parent_path() / "model.yaml").string();
  if (!parent_card.empty() && fs::exists(parent_card)) {
    const YAML::Node root = loadYamlFile(parent_card, "the warm start's model card");
    const YAML::Node section = root.IsMap() ? root["perception"] : YAML::Node();
    if (section && section.IsMap() && section["hough"]) hough = section["hough"];
  }
  YAML::Emitter e;
  e << YAML::BeginMap << YAML::Key << "perception" << YAML::Value << YAML::BeginMap << YAML::Key
    << "samples" << YAML::Value << (latent ? 3 : 1);
  if (hough.IsMap()) e << YAML::Key << "hough" << YAML::Value << hough;
  e << YAML::EndMap << YAML::EndMap;
  const std::string note = hough.IsMap()
                               ? "the Hough setting of " + parent_card +
                                     " (the warm start's) until simstack_tune_hough writes one"
                               : "simstack_tune_hough writes its hough: map";
  return "# read with the model; " + note + "\n" + e.c_str() + "\n";
}

/// The perception: section of a run's own card (model.yaml in its directory) when it holds a
/// Hough setting, which a resume keeps: one put there by hand (simstack_tune_hough's output)
/// must survive more steps. Empty when the run has no card or its card no hough: map.
std::string runCardPerceptionSection(const fs::path& card) {
  if (!fs::exists(card)) return "";
  const YAML::Node root = loadYamlFile(card.string(), "the run's model card");
  const YAML::Node section = root.IsMap() ? root["perception"] : YAML::Node();
  if (!section || !section.IsMap() || !section["hough"]) return "";
  YAML::Emitter e;
  e << YAML::BeginMap << YAML::Key << "perception" << YAML::Value << section << YAML::EndMap;
  return "# read with the model; kept from this run's card (" + card.string() +
         ") when it was resumed\n" + e.c_str() + "\n";
}

/// A config value as a person writes it: numbers in their shortest form (toYaml stores 0.05 as
/// 0.050000000000000003), a list on one line ([0.5, 1, 2]).
std::string writtenValue(const YAML::Node& n) {
  if (!n) return "(none)";
  if (n.IsSequence() || n.IsMap()) {
    std::string out = n.IsSequence() ? "[" : "{";
    for (auto it = n.begin(); it != n.end(); ++it) {
      if (it != n.begin()) out += ", ";
      out += n.IsSequence() ? writtenValue(*it)
                            : it->first.as<std::string>() + ": " + writtenValue(it->second);
    }
    return out + (n.IsSequence() ? "]" : "}");
  }
  const std::string s = n.Scalar();
  char* end = nullptr;
  const double v = std::strtod(s.c_str(), &end);
  return !s.empty() && end == s.c_str() + s.size() ? configValue(v) : s;
}

/// The fields of two YAML maps (a config's toYaml) whose values differ, as "key: a (checkpoint)
/// against key: b (config)" clauses; a list is compared whole.
std::string differingLines(const std::string& checkpoint, const std::string& config) {
  const YAML::Node a = YAML::Load(checkpoint), b = YAML::Load(config);
  std::string out;
  const auto differ = [&](const std::string& key) {
    const std::string was = writtenValue(a[key]), is = writtenValue(b[key]);
    if (was != is)
      out += (out.empty() ? "" : "; ") + key + ": " + was + " (checkpoint) against " + key + ": " +
             is + " (config)";
  };
  for (const auto& kv : a) differ(kv.first.as<std::string>());
  for (const auto& kv : b)
    if (!a[kv.first.as<std::string>()]) differ(kv.first.as<std::string>());
  return out.empty() ? "no field differs" : out;
}

/// The data a run trains on as a checkpoint records it (one line; the files' tags joined by
/// " + " for a mix): a resume on other data is refused, since a resumed run sees the data an
/// uninterrupted one would have. The generator's size range is not in a dataset's attributes,
/// so it cannot be compared.
std::string datasetTag(const DatasetMix& data) {
  std::string out;
  for (int k = 0; k < data.files(); ++k) {
    const DatasetInfo& info = data.file(k).info();
    out += (k ? " + " : "") +
           ("seed " + std::to_string(info.seed) + ", " + std::to_string(info.num_scenes) +
            " scenes of " + std::to_string(info.min_objects) + "-" +
            std::to_string(info.max_objects) + " objects, generator " +
            (info.generator_version.empty() ? "unknown" : info.generator_version));
  }
  return out;
}

/// The checkpoint format this trainer writes and resumes: the network, the optimizer's state
/// and the step in one archive, with metadata naming the dataset and the warm start.
constexpr int kCheckpointFormatVersion = 1;

/// The mesh catalogues of the data, one short line ("superquadrics", or the number of mesh
/// shapes and an FNV-1a hash of their names, per file): two datasets of one seed and size may
/// still hold other shapes.
std::string datasetMeshes(const DatasetMix& data) {
  std::string out;
  for (int k = 0; k < data.files(); ++k) {
    const std::vector<std::string>& names = data.file(k).info().mesh_names;
    std::uint64_t hash = 1469598103934665603ull;
    for (const std::string& n : names)
      for (const char c : n + ",") hash = (hash ^ static_cast<unsigned char>(c)) * 1099511628211ull;
    char text[64];
    std::snprintf(text, sizeof text, "%zu mesh shapes (names hashed %016llx)", names.size(),
                  static_cast<unsigned long long>(hash));
    out += (k ? " + " : "") + (names.empty() ? std::string("superquadrics") : std::string(text));
  }
  return out;
}

/// A checkpoint's metadata: its format, its dataset tag and meshes, the model the run was
/// warm-started from, and the run's training settings (TrainConfig::toYaml).
std::string checkpointMetadata(const DatasetMix& data, const std::string& init_from,
                               const TrainConfig& training) {
  YAML::Emitter e;
  e << YAML::BeginMap << YAML::Key << "format_version" << YAML::Value << kCheckpointFormatVersion
    << YAML::Key << "dataset" << YAML::Value << datasetTag(data) << YAML::Key << "meshes"
    << YAML::Value << datasetMeshes(data) << YAML::Key << "init_from" << YAML::Value << init_from
    << YAML::Key << "training" << YAML::Value << training.toYaml() << YAML::EndMap;
  return e.c_str();
}

/// The settings a resumed run may change: how it runs and reports, not what it learns. The
/// step count may grow (the learning rate's cosine then follows the new length: said).
const std::set<std::string> kResumableSettings = {"threads",
                                                  "checkpoint_every",
                                                  "validate_every",
                                                  "validation_views",
                                                  "validation_samples",
                                                  "init_from",
                                                  "steps"};

/// The training settings that differ between a checkpoint's run and `now`, other than
/// kResumableSettings ("" when none, or when the checkpoint does not record them).
std::string changedSettings(const std::string& recorded, const TrainConfig& now) {
  if (recorded.empty()) return "";
  const YAML::Node was = YAML::Load(recorded), is = YAML::Load(now.toYaml());
  std::string out;
  for (const auto& kv : is) {
    const std::string key = kv.first.as<std::string>();
    if (kResumableSettings.count(key)) continue;
    const std::string a = was[key] ? YAML::Dump(was[key]) : "(none)", b = YAML::Dump(kv.second);
    if (a != b) out += (out.empty() ? "" : ", ") + key + " " + a + " -> " + b;
  }
  return out;
}

/// A field of a checkpoint's metadata; empty when absent or unreadable.
std::string metadataField(const std::string& metadata, const char* key) {
  try {
    const YAML::Node n = YAML::Load(metadata);
    return n.IsMap() && n[key] && n[key].IsScalar() ? n[key].as<std::string>() : "";
  } catch (const YAML::Exception&) {
    return "";
  }
}

}  // namespace

double learningRate(const TrainConfig& tc, int64_t step) {
  const double progress = std::clamp(static_cast<double>(step) / tc.steps, 0.0, 1.0);
  return tc.final_learning_rate +
         0.5 * (tc.learning_rate - tc.final_learning_rate) * (1.0 + std::cos(M_PI * progress));
}

namespace {

/// How many of the last `validation_scenes` piles of `data` the warm start's parent `init_from`
/// trained on, from its provenance (model.pt's metadata: its dataset's seed, scene count and
/// validation split; scene i depends on the seed and i alone). 0 for a mix, another seed, or a
/// parent that records none.
int validationTrainedByParent(const std::string& init_from, const DatasetMix& data,
                              int validation_scenes) {
  if (init_from.empty() || data.files() != 1 || !fs::exists(init_from)) return 0;
  std::string metadata;
  try {
    loadCvae(init_from, nullptr, &metadata);
    const YAML::Node p = YAML::Load(metadata);
    if (!p.IsMap() || !p["dataset_seed"] || !p["dataset_scenes"] || !p["validation_scenes"])
      return 0;
    if (p["dataset_seed"].as<std::string>() != std::to_string(data.file(0).info().seed)) return 0;
    const long trained = p["dataset_scenes"].as<long>() - p["validation_scenes"].as<long>();
    const long first_validation = data.size() - validation_scenes;
    return static_cast<int>(std::max(0L, std::min<long>(trained, data.size()) - first_validation));
  } catch (const std::exception&) {  // a checkpoint or an older file: no provenance to compare
    return 0;
  }
}

}  // namespace

struct CvaeTrainer::Impl {
  std::string output_dir, command_line;
  CvaeConfig model_config;
  TrainConfig config;
  std::unique_ptr<DatasetMix> data;
  int train_scenes = 0;
  std::string card_perception;        // the card's perception: section, read before training
  std::string note;                   // what the trainer chose for the user (CvaeTrainer::note)
  int validation_seen_by_parent = 0;  // validation piles the warm start's parent trained on

  /// `trained_on` receives a resumed checkpoint's metadata (checkpointMetadata).
  Cvae loadOrCreate(bool resuming, const fs::path& checkpoint, std::string* trained_on) const;
  /// A resumed checkpoint's metadata against this run: another dataset is refused. The card's
  /// perception: section is the run card's own when it holds a Hough setting, else that of the
  /// model the run was warm-started from (returned; --init-from is not read with --resume).
  std::string resumeFrom(const std::string& metadata, const fs::path& out);
  int64_t restore(Cvae& model, torch::optim::Adam& optimizer, const fs::path& out) const;
  void validate(Cvae& model, const TrainingSampleBuilder& builder, TrainingReport* report) const;
  void saveCheckpoint(Cvae& model, torch::optim::Adam& optimizer, const std::string& init_from,
                      int64_t step) const;
  void writeModelFiles(const fs::path& out, Cvae& model, const TrainingReport& report,
                       bool posterior_measured) const;
  /// Counts this run's validation piles that the run's parent `init_from` trained on, and says
  /// so on stderr when there are some.
  void noteValidationTrainedByParent(const std::string& init_from);
};

void CvaeTrainer::Impl::noteValidationTrainedByParent(const std::string& init_from) {
  validation_seen_by_parent = validationTrainedByParent(init_from, *data, config.validation_scenes);
  if (validation_seen_by_parent == 0) return;
  const int first_validation = data->size() - config.validation_scenes;
  std::cerr << "note: " << validation_seen_by_parent << " of the last " << config.validation_scenes
            << " piles, this run's validation, were trained on by " << init_from
            << " (same seed): its validation figures flatter it (the card's provenance says so); "
               "from pile "
            << first_validation + validation_seen_by_parent
            << " on, the parent trained on none: fewer --validation-scenes, a larger dataset of "
               "the seed, or another seed keeps them apart\n";
}

CvaeTrainer::CvaeTrainer(const std::vector<std::string>& dataset_paths, const CvaeConfig& model,
                         const TrainConfig& training, const std::string& output_dir,
                         const std::string& command_line, const std::string& mesh_dir)
    : impl_(std::make_unique<Impl>()) {
  model.validate();
  training.validate();
  impl_->output_dir = output_dir;
  impl_->command_line = command_line;
  impl_->model_config = model;
  impl_->config = training;
  impl_->card_perception = cardPerceptionSection(training.init_from, model.hasLatentCode());
  impl_->data = std::make_unique<DatasetMix>(dataset_paths, mesh_dir);
  const DatasetMix& data = *impl_->data;
  for (int k = 0; k < data.files(); ++k)
    checkDatasetFitsModel(data.file(k).info(), model, data.path(k), "the model config");
  const int scenes = data.size();
  const std::string named = (data.files() > 1 ? "datasets " : "dataset ") + data.name();
  // A dataset smaller than the validation asked for (a newcomer's first run on a few dozen
  // piles): a quarter of it validates, and the note says so.
  if (scenes < 2)
    throw std::runtime_error(named + " has " + std::to_string(scenes) +
                             " scene: training needs at least 2 (one to train on, one to "
                             "validate on); generate more scenes");
  if (training.validation_scenes >= scenes) {
    impl_->config.validation_scenes = std::max(1, scenes / 4);
    impl_->note =
        named + " holds " + std::to_string(scenes) +
        " scenes, not more than validation_scenes = " + std::to_string(training.validation_scenes) +
        ": its last " + std::to_string(impl_->config.validation_scenes) +
        " are the validation (--validation-scenes chooses)";
  }
  impl_->train_scenes = scenes - impl_->config.validation_scenes;
  std::error_code ec;
  fs::create_directories(output_dir, ec);
  if (ec)
    throw std::runtime_error("cannot create output directory " + output_dir + ": " + ec.message());
}

CvaeTrainer::~CvaeTrainer() = default;

const std::string& CvaeTrainer::note() const { return impl_->note; }

TrainingReport CvaeTrainer::validateModel(const std::vector<std::string>& dataset_paths,
                                          const std::string& model_path,
                                          const TrainConfig& training,
                                          const std::string& mesh_dir) {
  training.validate();
  Cvae model = loadCvae(model_path);
  Impl impl;
  impl.model_config = model->config();
  impl.config = training;
  impl.data = std::make_unique<DatasetMix>(dataset_paths, mesh_dir);
  const DatasetMix& data = *impl.data;
  const CvaeConfig& mc = impl.model_config;
  for (int k = 0; k < data.files(); ++k)
    checkDatasetFitsModel(data.file(k).info(), mc, data.path(k), "model " + model_path);
  const int scenes = data.size();
  if (training.validation_scenes > scenes)
    throw std::runtime_error((data.files() > 1 ? "datasets " : "dataset ") + data.name() + " has " +
                             std::to_string(scenes) + " scenes, fewer than validation_scenes = " +
                             std::to_string(training.validation_scenes) +
                             ": give --validation-scenes " + std::to_string(scenes) + " or fewer");
  impl.train_scenes = scenes - training.validation_scenes;
  torch::set_num_threads(training.threads);
  torch::manual_seed(training.seed);
  const TrainingSampleBuilder builder(mc, scaledKinect(training.image_width, training.image_height),
                                      training.sensor_noise, training.overhead_share,
                                      parseSensorModel(training.sensor_model));
  TrainingReport report;
  impl.validate(model, builder, &report);
  return report;
}

Cvae CvaeTrainer::Impl::loadOrCreate(bool resuming, const fs::path& checkpoint,
                                     std::string* trained_on) const {
  const CvaeConfig& mc = model_config;
  // A resumed network is compared with the config's in restore(), which names what differs.
  Cvae model = resuming ? loadCvae(checkpoint.string(), nullptr, trained_on) : Cvae(mc);
  if (!resuming && !config.init_from.empty()) {
    const std::vector<std::string> fresh = warmStartCvae(model, config.init_from);
    std::cerr << "warm start from " << config.init_from << ": ";
    if (fresh.empty())
      std::cerr << "every tensor of this network taken from it";
    else
      std::cerr << fresh.size() << " tensors of this network are new:";
    for (const std::string& name : fresh) std::cerr << " " << name;
    std::cerr << "\n";
  }
  return model;
}

int64_t CvaeTrainer::Impl::restore(Cvae& model, torch::optim::Adam& optimizer,
                                   const fs::path& out) const {
  const CvaeConfig& mc = model_config;
  const fs::path checkpoint = out / "checkpoint.pt";
  // The network is the checkpoint's; the losses are this config's (training a model further
  // may change them), and the saved files say so.
  const std::string saved = model->config().toYaml();
  const bool same = saved == mc.toYaml();
  try {
    model->setConfig(mc);
  } catch (const std::invalid_argument&) {
    CvaeConfig network = model->config();  // the checkpoint's network with this config's losses
    network.copyLossSettings(mc);
    const std::string architecture = network.architecture;
    throw std::runtime_error(
        "checkpoint " + checkpoint.string() + " has another network than the config: " +
        differingLines(network.toYaml(), mc.toYaml()) + " (a resume needs the same network" +
        (architecture != mc.architecture ? ": --architecture " + architecture + " resumes it"
                                         : "") +
        "; --init-from warm-starts another)");
  }
  if (!same)
    std::cerr << "the checkpoint's loss settings are replaced by the config's: "
              << differingLines(saved, mc.toYaml()) << "\n";
  // The checkpoint holds its step and the optimizer's state (resumeFrom checked its format).
  torch::serialize::InputArchive archive;
  archive.load_from(checkpoint.string());
  torch::IValue step;
  torch::serialize::InputArchive adam;
  if (!archive.try_read("simstack_step", step) || !archive.try_read("simstack_optimizer", adam))
    throw std::runtime_error("checkpoint " + checkpoint.string() +
                             " holds no step or optimizer state: it cannot be resumed");
  optimizer.load(adam);
  const int64_t start = step.toInt();
  std::cerr << "resuming from step " << start << " (" << checkpoint.string() << ")\n";
  return start;
}

namespace {

/// Sums of the validation measures over views.
struct ValidationSums {
  double iou = 0, bce = 0, single = 0, best = 0, posterior = 0;
  int64_t disagree[2] = {0, 0}, occupied[2] = {0, 0};  // [seen, unseen]
  int views = 0;
};

/// Validation views and prior codes come from streams of their own, not from the training seed:
/// every run, and --validate-only, scores the same views with the same codes, so that two
/// models compare view by view. (1: the views of runs with the default seed before.)
constexpr uint64_t kValidationSeed = 1;

/// One validation view: S prior codes (and the posterior mean for a C-VAE) scored against the
/// truth; returns the expected-occupancy IoU.
double scoreValidationView(Cvae& model, const CvaeConfig& mc, const TrainingSample& s, int samples,
                           uint64_t code_seed, ValidationSums* sums) {
  const int r = mc.resolution;
  const Batch b = toBatch({s}, r);
  const torch::Tensor z =
      torch::randn({samples, mc.latent_size}, at::detail::createCPUGenerator(code_seed));
  // One condition shared by the codes (encoded once); the FC baseline, which ignores the code,
  // gets one per code so that its S (equal) outputs are scored like hypotheses.
  const CvaeOutput o = model->generate(
      mc.hasLatentCode() ? b.partial : b.partial.expand({samples, 2, r, r, r}).contiguous(), z);
  std::vector<std::vector<float>> preds;
  for (int j = 0; j < samples; ++j) preds.push_back(values(o.tsdf[j]));
  const OccupancyScores sc = scoreOccupancy(s.tsdf, preds);
  sums->iou += sc.iou;
  sums->bce += sc.bce;
  double best = 0;
  for (const std::vector<float>& p : preds) {
    const double one = scoreOccupancy(s.tsdf, {p}).iou;
    sums->single += one / samples;
    best = std::max(best, one);
  }
  sums->best += best;
  if (mc.hasLatentCode()) {
    // The code the encoder gives when it sees the ground truth (posterior mean): better than
    // prior codes only when the code carries what the view does not show. Drawn from no
    // stream: how often a run validates must not change what it trains.
    const torch::Tensor mu = model->posteriorMean(b.partial, b.tsdf, b.votes);
    sums->posterior +=
        scoreOccupancy(s.tsdf, {values(model->decodeCodes(b.partial, mu).tsdf[0])}).iou;
  }
  const torch::Tensor votes = (o.tsdf <= 0).sum(0).flatten();  // per voxel: hypotheses occupied
  const torch::Tensor seen = (b.partial[0][1] > 0.5).flatten();
  const torch::Tensor any = votes > 0, split = any & (votes < samples);
  for (int u = 0; u < 2; ++u) {
    const torch::Tensor region = u == 0 ? seen : ~seen;
    sums->occupied[u] += (any & region).sum().item<int64_t>();
    sums->disagree[u] += (split & region).sum().item<int64_t>();
  }
  ++sums->views;
  return sc.iou;
}

}  // namespace

// Validation set: `validation_views` fixed views per held-out scene, `validation_samples` codes
// each. Besides IoU and BCE it measures whether the latent space is used (scoreValidationView).
void CvaeTrainer::Impl::validate(Cvae& model, const TrainingSampleBuilder& builder,
                                 TrainingReport* report) const {
  model->eval();
  torch::NoGradGuard no_grad;
  const int n = data->size();
  ValidationSums sums;
  std::vector<double> scene_iou;
  for (int k = train_scenes; k < n; ++k) {
    // One stream per scene, its views drawn in turn: the first view is the one a single-view
    // validation drew.
    std::mt19937_64 rng(mix(kValidationSeed ^ 0xA11DA7Eull, static_cast<uint64_t>(k)));
    const SceneRecord record = data->read(k);
    double scene_sum = 0;
    for (int v = 0; v < config.validation_views; ++v) {
      const uint64_t code_seed = mix(mix(kValidationSeed ^ 0xC0DE5ull, static_cast<uint64_t>(k)),
                                     static_cast<uint64_t>(v));
      scene_sum += scoreValidationView(model, model_config, builder.build(record, rng),
                                       config.validation_samples, code_seed, &sums);
    }
    scene_iou.push_back(scene_sum / config.validation_views);
  }
  const double views = sums.views;
  report->validation_iou = sums.iou / views;
  double spread = 0;
  for (double x : scene_iou) spread += (x - report->validation_iou) * (x - report->validation_iou);
  const double m = static_cast<double>(scene_iou.size());
  report->validation_iou_se = m > 1 ? std::sqrt(spread / (m - 1) / m) : 0.0;
  report->validation_bce = sums.bce / views;
  report->validation_single_iou = sums.single / views;
  report->validation_best_iou = sums.best / views;
  report->validation_posterior_iou = model_config.hasLatentCode()
                                         ? sums.posterior / views
                                         : std::numeric_limits<double>::quiet_NaN();
  auto share = [](int64_t a, int64_t b) { return b > 0 ? static_cast<double>(a) / b : 0.0; };
  report->validation_disagreement =
      share(sums.disagree[0] + sums.disagree[1], sums.occupied[0] + sums.occupied[1]);
  report->validation_disagreement_seen = share(sums.disagree[0], sums.occupied[0]);
  report->validation_disagreement_unseen = share(sums.disagree[1], sums.occupied[1]);
  report->validation_unseen_share = share(sums.disagree[1], sums.disagree[0] + sums.disagree[1]);
  model->train();
}

// model.pt (weights, config and provenance in one archive) and its card, model.yaml.
void CvaeTrainer::Impl::writeModelFiles(const fs::path& out, Cvae& model,
                                        const TrainingReport& report,
                                        bool posterior_measured) const {
  YAML::Emitter meta;
  meta << YAML::BeginMap;
  meta << YAML::Key << "command" << YAML::Value << command_line;
  // A mix is named by its files joined by " + ", and so are their seeds and sizes.
  std::string seeds, sizes;
  for (int k = 0; k < data->files(); ++k) {
    seeds += (k ? " + " : "") + std::to_string(data->file(k).info().seed);
    sizes += (k ? " + " : "") + std::to_string(data->file(k).size());
  }
  meta << YAML::Key << "dataset" << YAML::Value << data->name();
  if (data->files() == 1) {
    meta << YAML::Key << "dataset_seed" << YAML::Value << data->file(0).info().seed;
    meta << YAML::Key << "dataset_scenes" << YAML::Value << data->size();
  } else {
    meta << YAML::Key << "dataset_seed" << YAML::Value << seeds;
    meta << YAML::Key << "dataset_scenes" << YAML::Value << sizes;
  }
  meta << YAML::Key << "validation_scenes" << YAML::Value << config.validation_scenes;
  meta << YAML::Key << "validation_views" << YAML::Value << config.validation_views;
  meta << YAML::Key << "validation_samples" << YAML::Value << config.validation_samples;
  if (validation_seen_by_parent > 0)  // the warm start's parent trained on them
    meta << YAML::Key << "validation_trained_by_parent" << YAML::Value << validation_seen_by_parent;
  meta << YAML::Key << "steps" << YAML::Value << report.steps;
  meta << YAML::Key << "final_losses" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
       << "total" << YAML::Value << report.total << YAML::Key << "tsdf" << YAML::Value
       << report.tsdf << YAML::Key << "partial" << YAML::Value << report.partial << YAML::Key
       << "votes" << YAML::Value << report.votes << YAML::Key << "mmd" << YAML::Value << report.mmd
       << YAML::Key << "occupancy" << YAML::Value << report.occupancy << YAML::Key << "iou"
       << YAML::Value << report.iou << YAML::EndMap;
  meta << YAML::Key << "validation" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
       << "iou" << YAML::Value << report.validation_iou << YAML::Key << "iou_se" << YAML::Value
       << report.validation_iou_se << YAML::Key << "bce" << YAML::Value << report.validation_bce
       << YAML::Key << "disagreement" << YAML::Value << report.validation_disagreement;
  if (std::isfinite(report.validation_posterior_iou))
    meta << YAML::Key << "posterior_code_iou" << YAML::Value << report.validation_posterior_iou;
  meta << YAML::Key << "single_code_iou" << YAML::Value << report.validation_single_iou << YAML::Key
       << "best_code_iou" << YAML::Value << report.validation_best_iou << YAML::Key
       << "disagreement_seen" << YAML::Value << report.validation_disagreement_seen << YAML::Key
       << "disagreement_unseen" << YAML::Value << report.validation_disagreement_unseen << YAML::Key
       << "unseen_share_of_disagreement" << YAML::Value << report.validation_unseen_share;
  meta << YAML::EndMap;
  if (posterior_measured) {  // C-VAE steps trained in this run
    meta << YAML::Key << "posterior" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
         << "mu_rms" << YAML::Value << report.posterior_mu_rms << YAML::Key << "sigma"
         << YAML::Value << report.posterior_sigma << YAML::EndMap;
  }
  meta << YAML::Key << "samples_per_second" << YAML::Value << report.samples_per_second;
  meta << YAML::EndMap;
  saveCvae((out / "model.pt").string(), model, meta.c_str());

  auto indented = [](std::ostream& os, const std::string& text) {
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) os << "  " << line << "\n";
  };
  // Written whole or not at all, as model.pt is: a card cut short would be read as settings.
  StagedFile card((out / "model.yaml").string());
  std::ofstream yaml(card.path());
  yaml << "# simstack model card (the network config is also stored inside model.pt)\nmodel:\n";
  indented(yaml, model_config.toYaml());
  yaml << "training:\n";
  indented(yaml, config.toYaml());
  yaml << "provenance:\n";
  indented(yaml, meta.c_str());
  yaml << card_perception;
  yaml.close();
  if (!yaml) throw std::runtime_error("cannot write " + (out / "model.yaml").string());
  card.commit();
}

std::string CvaeTrainer::Impl::resumeFrom(const std::string& metadata, const fs::path& out) {
  const fs::path checkpoint = out / "checkpoint.pt";
  const std::string now = datasetTag(*data);
  const std::string format = metadataField(metadata, "format_version");
  if (format != std::to_string(kCheckpointFormatVersion))
    throw std::runtime_error(
        "checkpoint " + checkpoint.string() + " is in checkpoint format " +
        (format.empty() ? std::string("0 (no format_version in its metadata)") : format) +
        "; this trainer resumes format " + std::to_string(kCheckpointFormatVersion) +
        ": warm-start a new run from it (--init-from) instead of --resume");
  const std::string was = metadataField(metadata, "dataset");
  if (!was.empty() && was != now)
    throw std::runtime_error("checkpoint " + checkpoint.string() + " was trained on a dataset of " +
                             was + "; " + data->name() + " holds " + now +
                             ": resume on the run's own dataset, or warm-start a new run from "
                             "the checkpoint (--init-from) to train on this one");
  const std::string meshes = metadataField(metadata, "meshes");
  if (!meshes.empty() && meshes != datasetMeshes(*data))
    throw std::runtime_error(
        "checkpoint " + checkpoint.string() + " was trained on piles of " + meshes + "; " +
        data->name() + " holds " + datasetMeshes(*data) +
        ": resume on the run's own dataset, or warm-start a new run (--init-from)");
  const std::string recorded = metadataField(metadata, "training");
  if (const std::string changed = changedSettings(recorded, config); !changed.empty())
    throw std::runtime_error("checkpoint " + checkpoint.string() +
                             " was trained with other settings (" + changed +
                             "): a resume continues the run as it was started (only threads, "
                             "checkpoint, validation counts and a longer --steps may change); "
                             "warm-start a new run from it (--init-from) to train otherwise");
  if (!recorded.empty()) {
    const YAML::Node was = YAML::Load(recorded);
    if (was["steps"] && was["steps"].as<int64_t>() != config.steps)
      std::cerr << "note: the run was started for " << was["steps"].as<int64_t>()
                << " steps and now trains to " << config.steps
                << " (the learning rate's cosine follows the new length)\n";
  }
  // The run's parent is the one it started from: an --init-from given to the resume is not
  // read (its weights, its card's Hough setting, its name on the card).
  const std::string parent = metadataField(metadata, "init_from");
  if (!config.init_from.empty() && config.init_from != parent)
    std::cerr << "note: --init-from " << config.init_from
              << " is not read on a resume: the run continues from its checkpoint"
              << (parent.empty() ? std::string(", started afresh")
                                 : ", warm-started from " + parent)
              << "\n";
  card_perception = cardPerceptionSection(parent, model_config.hasLatentCode());
  if (const std::string kept = runCardPerceptionSection(out / "model.yaml"); !kept.empty())
    card_perception = kept;
  config.init_from = parent;  // the card's training section names the run's parent
  return parent;
}

namespace {

/// Weights a non-finite gradient reached, or batch-norm statistics that overflowed, are not
/// written over the last good checkpoint (the loader refuses either): std::runtime_error.
void requireFinite(Cvae& model, int64_t step) {
  for (const auto& p : model->named_parameters())
    if (!torch::isfinite(p.value()).all().item<bool>())
      throw std::runtime_error("step " + std::to_string(step) + ": the network's weight " +
                               p.key() +
                               " is not finite (a gradient overflowed; a learning rate too high "
                               "for the run?); the last checkpoint stays as it was");
  for (const auto& b : model->named_buffers())
    if (b.value().is_floating_point() && !torch::isfinite(b.value()).all().item<bool>())
      throw std::runtime_error("step " + std::to_string(step) + ": the network's statistic " +
                               b.key() +
                               " is not finite (activations overflowed; a damaged --init-from "
                               "model or a learning rate too high?); the last checkpoint stays "
                               "as it was");
}

/// The figures in the card of a model a run already wrote at `steps` (<out>/model.pt and
/// model.yaml), or nothing when there is no such model or its card cannot be read.
std::optional<TrainingReport> writtenReport(const fs::path& out, int64_t steps) {
  if (!fs::exists(out / "model.pt") || !fs::exists(out / "model.yaml")) return std::nullopt;
  try {
    const YAML::Node p = YAML::LoadFile((out / "model.yaml").string())["provenance"];
    if (!p || !p["steps"] || p["steps"].as<int64_t>() != steps) return std::nullopt;
    TrainingReport r;
    r.steps = steps;
    // (section of the card's provenance, field, report member)
    const std::vector<std::tuple<const char*, const char*, double*>> fields = {
        {"final_losses", "total", &r.total},
        {"final_losses", "tsdf", &r.tsdf},
        {"final_losses", "partial", &r.partial},
        {"final_losses", "votes", &r.votes},
        {"final_losses", "mmd", &r.mmd},
        {"final_losses", "occupancy", &r.occupancy},
        {"final_losses", "iou", &r.iou},
        {"validation", "iou", &r.validation_iou},
        {"validation", "iou_se", &r.validation_iou_se},
        {"validation", "bce", &r.validation_bce},
        {"validation", "disagreement", &r.validation_disagreement},
        {"validation", "posterior_code_iou", &r.validation_posterior_iou},
        {"validation", "single_code_iou", &r.validation_single_iou},
        {"validation", "best_code_iou", &r.validation_best_iou},
        {"validation", "disagreement_seen", &r.validation_disagreement_seen},
        {"validation", "disagreement_unseen", &r.validation_disagreement_unseen},
        {"validation", "unseen_share_of_disagreement", &r.validation_unseen_share},
        {"posterior", "mu_rms", &r.posterior_mu_rms},
        {"posterior", "sigma", &r.posterior_sigma}};
    for (const auto& [section, key, to] : fields)
      if (p[section] && p[section][key]) *to = p[section][key].as<double>();
    if (p["samples_per_second"]) r.samples_per_second = p["samples_per_second"].as<double>();
    return r;
  } catch (const YAML::Exception&) {
    return std::nullopt;
  }
}

}  // namespace

// One file holds the network, the optimizer's state and the step, written beside its place
// and renamed into it: a run stopped by an error or a kill resumes from the previous
// checkpoint or from this one, never from parts of both. state.yaml repeats the step for
// people and scripts.
void CvaeTrainer::Impl::saveCheckpoint(Cvae& model, torch::optim::Adam& optimizer,
                                       const std::string& init_from, int64_t step) const {
  requireFinite(model, step);
  const fs::path out(output_dir);
  saveCvae((out / "checkpoint.pt").string(), model, checkpointMetadata(*data, init_from, config),
           [&](torch::serialize::OutputArchive& archive) {
             torch::serialize::OutputArchive adam;
             optimizer.save(adam);
             archive.write("simstack_optimizer", adam);
             archive.write("simstack_step", torch::IValue(step));
           });
  const fs::path state_tmp = out / "state.yaml.tmp";
  {
    std::ofstream state(state_tmp.string());
    state << "step: " << step << "\n";
    if (!state.flush()) throw std::runtime_error("cannot write " + state_tmp.string());
  }
  fs::rename(state_tmp, out / "state.yaml");
}

namespace {

/// The run directory held by one trainer for its run: a second (a --resume started twice)
/// would write the same checkpoint and log. flock on the directory itself: released when the
/// process ends, however it ends, and nothing is left behind.
class RunDirectoryLock {
 public:
  explicit RunDirectoryLock(const fs::path& dir)
      : fd_(::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC)) {
    if (fd_ < 0)
      throw std::runtime_error("cannot open the run directory " + dir.string() + ": " +
                               std::strerror(errno));
    if (::flock(fd_, LOCK_EX | LOCK_NB) == 0) return;
    const int err = errno;
    ::close(fd_);
    throw std::runtime_error(err == EWOULDBLOCK
                                 ? "another training runs in " + dir.string() +
                                       " (it holds the directory): let it end, or stop it "
                                       "and --resume"
                                 : "cannot lock the run directory " + dir.string() + ": " +
                                       std::strerror(err));
  }
  ~RunDirectoryLock() { ::close(fd_); }
  RunDirectoryLock(const RunDirectoryLock&) = delete;
  RunDirectoryLock& operator=(const RunDirectoryLock&) = delete;

 private:
  int fd_;
};

}  // namespace

TrainingReport CvaeTrainer::run(bool resume, const TrainingProgressCallback& progress,
                                const std::function<bool()>& stop) {
  const TrainConfig& tc = impl_->config;
  const CvaeConfig& mc = impl_->model_config;
  const fs::path out(impl_->output_dir);
  const RunDirectoryLock lock(out);
  torch::set_num_threads(tc.threads);
  torch::manual_seed(tc.seed);
  const fs::path checkpoint = out / "checkpoint.pt";
  const bool resuming = resume && fs::exists(checkpoint);
  if (resume && !resuming)
    throw std::runtime_error("--resume: no checkpoint to resume in " + out.string() +
                             " (checkpoint.pt); start without --resume");
  std::string trained_on;  // the checkpoint's metadata
  Cvae model = impl_->loadOrCreate(resuming, checkpoint, &trained_on);
  const std::string init_from = resuming ? impl_->resumeFrom(trained_on, out) : tc.init_from;
  impl_->noteValidationTrainedByParent(init_from);
  torch::optim::Adam optimizer(model->parameters(), torch::optim::AdamOptions(tc.learning_rate));
  const int64_t start = resuming ? impl_->restore(model, optimizer, out) : 0;
  if (start > tc.steps)
    throw std::runtime_error("the checkpoint in " + out.string() + " is at step " +
                             std::to_string(start) + ", past steps = " + std::to_string(tc.steps) +
                             ": --steps " + std::to_string(start) +
                             " or more continues the run (fewer would rewind it)");

  const TrainingSampleBuilder builder(mc, scaledKinect(tc.image_width, tc.image_height),
                                      tc.sensor_noise, tc.overhead_share,
                                      parseSensorModel(tc.sensor_model));
  TrainingLog log(out / "train_log.csv", resume && start > 0, start);
  auto save_checkpoint = [&](int64_t step) {
    log.flush();
    impl_->saveCheckpoint(model, optimizer, init_from, step);
  };

  TrainingReport report;
  RecentSteps recent;
  const auto t0 = std::chrono::steady_clock::now();
  int64_t trained = 0;
  model->train();
  {
    BatchQueue batches(tc, builder, *impl_->data, impl_->train_scenes, mc.resolution, start);
    for (int64_t step = start; step < tc.steps; ++step) {
      Batch batch;
      try {
        batch = batches.next();
      } catch (const std::runtime_error& e) {
        throw std::runtime_error("building training samples from " + impl_->data->name() +
                                 " failed: " + e.what());
      }
      for (auto& group : optimizer.param_groups())
        static_cast<torch::optim::AdamOptions&>(group.options()).lr(learningRate(tc, step));
      // The step's draws (posterior noise, the MMD's prior codes, dropout) from a stream of its
      // own: a run stopped and resumed at any checkpoint trains as the uninterrupted one.
      torch::manual_seed(mix(tc.seed, static_cast<uint64_t>(step)));
      optimizer.zero_grad();
      const CvaeOutput o = model->forward(batch.partial, batch.tsdf, batch.votes);
      const CvaeLosses l =
          computeLosses(o, batch.partial, batch.tsdf, batch.votes, mc, batch.vote_weight);
      // A loss that is not finite would carry NaN into every weight and checkpoint after it.
      if (!std::isfinite(l.total.item<double>()))
        throw std::runtime_error("step " + std::to_string(step + 1) +
                                 ": the loss is not finite (a learning rate too high for the "
                                 "run?); the last checkpoint stays as it was");
      l.total.backward();
      optimizer.step();
      ++trained;
      recent.add(l, o, &report);
      const double seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      report.samples_per_second = trained * tc.batch_size / seconds;
      const bool validating = (step + 1) % tc.validate_every == 0 || step + 1 == tc.steps;
      if (validating) impl_->validate(model, builder, &report);
      if ((step + 1) % 10 == 0 || validating)
        log.write(step + 1, recent.losses.back(), report, validating, !recent.posterior.empty());
      const bool checkpointed = (step + 1) % tc.checkpoint_every == 0;
      if (checkpointed) save_checkpoint(step + 1);
      if (progress) {
        const auto& a = recent.losses.back();
        progress({step + 1, tc.steps, start, a.total, a.tsdf, a.votes, a.mmd, report.validation_iou,
                  report.samples_per_second, seconds});
      }
      if (stop && step + 1 < tc.steps && stop()) {
        if (!checkpointed) save_checkpoint(step + 1);
        throw TrainingStopped("stopped at step " + std::to_string(step + 1) + " of " +
                                  std::to_string(tc.steps) + ": " + checkpoint.string() +
                                  " holds it; --resume continues the run",
                              step + 1);
      }
    }
  }
  report.steps = tc.steps;
  report.steps_trained = trained;
  if (trained == 0) {
    // The run had reached its steps: a model it wrote stays as it is (its card's losses and
    // posterior are those of the steps that trained it).
    if (std::optional<TrainingReport> written = writtenReport(out, tc.steps)) return *written;
  }
  save_checkpoint(tc.steps);
  if (trained == 0) {
    // Nothing left to train (a resumed run that had reached its steps): still report the
    // figures of the model being written, from the log and a fresh validation.
    impl_->validate(model, builder, &report);
    LossRow row;
    double rate = 0.0;
    if (log.lastRow(&row, &rate)) {
      recent.losses.push_back(row);
      report.samples_per_second = rate;
    }
  }
  recent.meanInto(&report);
  impl_->writeModelFiles(out, model, report, !recent.posterior.empty());
  return report;
}

}  // namespace simstack
