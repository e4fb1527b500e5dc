#include "simstack/model/cvae_trainer.h"

#include <omp.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <numeric>
#include <thread>

#include "simstack/dataset/dataset.h"
#include "simstack/eval/occupancy.h"
#include "simstack/model/cvae.h"
#include "simstack/model/training_sample.h"
#include "simstack/tools/progress.h"

namespace fs = std::filesystem;

namespace simstack {
namespace {

uint64_t mix(uint64_t a, uint64_t b) {
  uint64_t z = a * 0x9E3779B97F4A7C15ull + b + 0x632BE59BD9B4E019ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

std::vector<float> values(const torch::Tensor& t) {
  const torch::Tensor c = t.contiguous();
  return std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
}

struct Batch {
  torch::Tensor partial, tsdf, votes;
};

Batch toBatch(const std::vector<TrainingSample>& samples, int r) {
  const int64_t b = static_cast<int64_t>(samples.size());
  Batch batch;
  batch.partial = torch::empty({b, 2, r, r, r});
  batch.tsdf = torch::empty({b, 1, r, r, r});
  batch.votes = torch::empty({b, 3, r, r, r});
  for (int64_t i = 0; i < b; ++i) {
    std::copy(samples[i].partial.begin(), samples[i].partial.end(),
              batch.partial[i].data_ptr<float>());
    std::copy(samples[i].tsdf.begin(), samples[i].tsdf.end(), batch.tsdf[i].data_ptr<float>());
    std::copy(samples[i].votes.begin(), samples[i].votes.end(), batch.votes[i].data_ptr<float>());
  }
  return batch;
}

}  // namespace

double learningRate(const TrainConfig& tc, int64_t step) {
  const double progress = std::clamp(static_cast<double>(step) / tc.steps, 0.0, 1.0);
  return tc.final_learning_rate +
         0.5 * (tc.learning_rate - tc.final_learning_rate) * (1.0 + std::cos(M_PI * progress));
}

struct CvaeTrainer::Impl {
  std::string dataset_path, output_dir, command_line;
  CvaeConfig model_config;
  TrainConfig config;
  std::unique_ptr<DatasetReader> reader;
  int train_scenes = 0;
};

CvaeTrainer::CvaeTrainer(const std::string& dataset_path, const CvaeConfig& model,
                         const TrainConfig& training, const std::string& output_dir,
                         const std::string& command_line)
    : impl_(std::make_unique<Impl>()) {
  model.validate();
  training.validate();
  impl_->dataset_path = dataset_path;
  impl_->output_dir = output_dir;
  impl_->command_line = command_line;
  impl_->model_config = model;
  impl_->config = training;
  impl_->reader = std::make_unique<DatasetReader>(dataset_path);
  const DatasetInfo& info = impl_->reader->info();
  if (info.resolution != model.resolution || std::abs(info.extent_m - model.extent_m) > 1e-9) {
    throw std::runtime_error("dataset " + dataset_path + " has " + std::to_string(info.resolution) +
                             "^3 grids over " + std::to_string(info.extent_m) +
                             " m, the model config wants " + std::to_string(model.resolution) +
                             "^3 over " + std::to_string(model.extent_m) + " m");
  }
  if (std::abs(info.truncation_m - model.truncation_m()) > 1e-9) {
    throw std::runtime_error("dataset " + dataset_path + " is truncated at " +
                             std::to_string(info.truncation_m) + " m, the model config at " +
                             std::to_string(model.truncation_m()) + " m");
  }
  impl_->train_scenes = info.num_scenes - training.validation_scenes;
  if (impl_->train_scenes < 1) {
    throw std::runtime_error("dataset " + dataset_path + " has " + std::to_string(info.num_scenes) +
                             " scenes; more than validation_scenes = " +
                             std::to_string(training.validation_scenes) + " are needed");
  }
  std::error_code ec;
  fs::create_directories(output_dir, ec);
  if (ec)
    throw std::runtime_error("cannot create output directory " + output_dir + ": " + ec.message());
}

CvaeTrainer::~CvaeTrainer() = default;

TrainingReport CvaeTrainer::run(bool resume) {
  const TrainConfig& tc = impl_->config;
  const CvaeConfig& mc = impl_->model_config;
  const int r = mc.resolution;
  const fs::path out(impl_->output_dir);
  torch::set_num_threads(tc.threads);
  torch::manual_seed(tc.seed);
  int64_t start = 0;
  const fs::path checkpoint = out / "checkpoint.pt", optim_file = out / "optimizer.pt",
                 state_file = out / "state.yaml";
  const bool resuming = resume && fs::exists(checkpoint) && fs::exists(state_file);
  Cvae model = resuming ? loadCvae(checkpoint.string(), &mc) : Cvae(mc);
  if (!resuming && !tc.init_from.empty()) {
    const std::vector<std::string> fresh = warmStartCvae(model, tc.init_from);
    std::cerr << "warm start from " << tc.init_from << ": ";
    if (fresh.empty())
      std::cerr << "every tensor of this network taken from it";
    else
      std::cerr << fresh.size() << " tensors of this network are new:";
    for (const std::string& name : fresh) std::cerr << " " << name;
    std::cerr << "\n";
  }
  torch::optim::Adam optimizer(model->parameters(), torch::optim::AdamOptions(tc.learning_rate));
  if (resuming) {
    // The network is the checkpoint's; the losses are this config's (training a model further
    // may change them), and the saved files say so.
    const bool same = model->config().toYaml() == mc.toYaml();
    try {
      model->setConfig(mc);
    } catch (const std::invalid_argument&) {
      throw std::runtime_error("checkpoint " + checkpoint.string() +
                               " has another network than the config:\n" +
                               model->config().toYaml() + "\nagainst\n" + mc.toYaml());
    }
    if (!same) std::cerr << "the checkpoint's loss settings are replaced by the config's\n";
    if (fs::exists(optim_file)) torch::load(optimizer, optim_file.string());
    start = YAML::LoadFile(state_file.string())["step"].as<int64_t>();
    torch::manual_seed(mix(tc.seed, static_cast<uint64_t>(start)));
    std::cerr << "resuming from step " << start << " (" << checkpoint.string() << ")\n";
  }

  // Batches are made by a worker thread ahead of the optimiser; sample (step, i) depends only
  // on the seed, so a resumed run sees the data an uninterrupted one would have.
  const PinholeCamera camera = scaledKinect(tc.image_width, tc.image_height);
  const TrainingSampleBuilder builder(mc, camera, tc.sensor_noise);
  std::mutex mutex;
  std::condition_variable cv;
  std::deque<std::pair<int64_t, Batch>> queue;
  std::string worker_error;
  bool stop = false;
  std::thread worker([&] {
    omp_set_num_threads(1);
    for (int64_t step = start; step < tc.steps; ++step) {
      std::vector<TrainingSample> samples;
      try {
        for (int i = 0; i < tc.batch_size; ++i) {
          std::mt19937_64 rng(mix(tc.seed, static_cast<uint64_t>(step) * 1024 + i));
          std::uniform_int_distribution<int> pick(0, impl_->train_scenes - 1);
          samples.push_back(builder.build(impl_->reader->read(pick(rng)), rng));
        }
      } catch (const std::exception& e) {
        std::lock_guard<std::mutex> lock(mutex);
        worker_error = e.what();
        cv.notify_all();
        return;
      }
      Batch batch = toBatch(samples, r);
      std::unique_lock<std::mutex> lock(mutex);
      cv.wait(lock, [&] { return queue.size() < 3 || stop; });
      if (stop) return;
      queue.emplace_back(step, std::move(batch));
      cv.notify_all();
    }
  });
  auto finish_worker = [&] {
    {
      std::lock_guard<std::mutex> lock(mutex);
      stop = true;
    }
    cv.notify_all();
    worker.join();
  };

  // Validation set: one fixed view per held-out scene, three codes each. Besides IoU and BCE
  // it measures whether the latent space is used: how often the three hypotheses disagree.
  auto validate = [&](TrainingReport* report) {
    model->eval();
    torch::NoGradGuard no_grad;
    const int n = impl_->reader->size();
    double iou = 0, bce = 0, posterior_iou = 0;
    int64_t disagree = 0, predicted = 0;
    int count = 0;
    for (int k = impl_->train_scenes; k < n; ++k) {
      std::mt19937_64 rng(mix(tc.seed ^ 0xA11DA7Eull, static_cast<uint64_t>(k)));
      const TrainingSample s = builder.build(impl_->reader->read(k), rng);
      const Batch b = toBatch({s}, r);
      const int samples = 3;
      const torch::Tensor z = torch::randn({samples, mc.latent_size});
      const CvaeOutput o = model->generate(b.partial.expand({samples, 2, r, r, r}).contiguous(), z);
      std::vector<std::vector<float>> preds;
      for (int j = 0; j < samples; ++j) preds.push_back(values(o.tsdf[j]));
      const OccupancyScores sc = scoreOccupancy(s.tsdf, preds);
      iou += sc.iou;
      bce += sc.bce;
      if (mc.hasLatentCode()) {
        // The code the encoder gives when it sees the ground truth (posterior mean): better
        // than prior codes only when the code carries what the view does not show.
        const torch::Tensor mu = model->forward(b.partial, b.tsdf, b.votes).mu;
        posterior_iou +=
            scoreOccupancy(s.tsdf, {values(model->generate(b.partial, mu).tsdf[0])}).iou;
      }
      const torch::Tensor votes = (o.tsdf <= 0).sum(0);  // per voxel: hypotheses occupied
      predicted += (votes > 0).sum().item<int64_t>();
      disagree += ((votes > 0) & (votes < samples)).sum().item<int64_t>();
      ++count;
    }
    report->validation_iou = iou / count;
    report->validation_bce = bce / count;
    report->validation_posterior_iou =
        mc.hasLatentCode() ? posterior_iou / count : std::numeric_limits<double>::quiet_NaN();
    report->validation_disagreement = predicted > 0 ? static_cast<double>(disagree) / predicted : 0;
    model->train();
  };

  std::ofstream log((out / "train_log.csv").string(),
                    resume && start > 0 ? std::ios::app : std::ios::trunc);
  if (!log) throw std::runtime_error("cannot write " + (out / "train_log.csv").string());
  log.seekp(0, std::ios::end);
  if (log.tellp() == 0)  // a new log (also when a finished model is trained further)
    log << "step,total,tsdf,partial,votes,mmd,occupancy,samples_per_s,validation_iou,"
           "validation_bce,validation_disagreement,posterior_mu_rms,posterior_sigma,"
           "validation_posterior_iou\n";
  auto save_checkpoint = [&](int64_t step) {
    saveCvae(checkpoint.string(), model);
    torch::save(optimizer, optim_file.string());
    std::ofstream(state_file.string()) << "step: " << step << "\n";
    log.flush();
  };

  TrainingReport report;
  std::deque<std::array<double, 6>> recent;
  // The encoder's posterior on the training batches (train mode; in eval mode BatchNorm's
  // running statistics give other codes): mean square of mu and mean sigma, last 50 steps.
  std::deque<std::array<double, 2>> posterior;
  ProgressBar bar(mc.hasLatentCode() ? "training C-VAE" : "training " + mc.architecture, tc.steps,
                  start);
  auto t0 = std::chrono::steady_clock::now();
  int64_t trained = 0;
  model->train();
  for (int64_t step = start; step < tc.steps; ++step) {
    Batch batch;
    {
      std::unique_lock<std::mutex> lock(mutex);
      cv.wait(lock, [&] { return !queue.empty() || !worker_error.empty(); });
      if (queue.empty()) {
        lock.unlock();
        finish_worker();
        throw std::runtime_error("building training samples from " + impl_->dataset_path +
                                 " failed: " + worker_error);
      }
      batch = std::move(queue.front().second);
      queue.pop_front();
      cv.notify_all();
    }
    for (auto& group : optimizer.param_groups())
      static_cast<torch::optim::AdamOptions&>(group.options()).lr(learningRate(tc, step));
    optimizer.zero_grad();
    const CvaeOutput o = model->forward(batch.partial, batch.tsdf, batch.votes);
    const CvaeLosses l = computeLosses(o, batch.partial, batch.tsdf, batch.votes, mc);
    l.total.backward();
    optimizer.step();
    ++trained;
    recent.push_back({l.total.item<double>(), l.tsdf.item<double>(), l.partial.item<double>(),
                      l.votes.item<double>(), l.mmd.item<double>(), l.occupancy.item<double>()});
    if (recent.size() > 50) recent.pop_front();
    if (o.mu.defined()) {
      torch::NoGradGuard no_grad;
      posterior.push_back(
          {o.mu.pow(2).mean().item<double>(), torch::exp(0.5 * o.logvar).mean().item<double>()});
      if (posterior.size() > 50) posterior.pop_front();
      double mu_sq = 0.0, sigma = 0.0;
      for (const auto& p : posterior) {
        mu_sq += p[0] / posterior.size();
        sigma += p[1] / posterior.size();
      }
      report.posterior_mu_rms = std::sqrt(mu_sq);
      report.posterior_sigma = sigma;
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    report.samples_per_second = trained * tc.batch_size / seconds;
    const bool validating = (step + 1) % tc.validate_every == 0 || step + 1 == tc.steps;
    if (validating) validate(&report);
    if ((step + 1) % 10 == 0 || validating) {
      const auto& a = recent.back();
      log << step + 1;
      for (double v : a) log << "," << v;
      log << "," << report.samples_per_second;
      if (validating) {
        log << "," << report.validation_iou << "," << report.validation_bce << ","
            << report.validation_disagreement << ",";
        if (posterior.empty()) {
          log << ",";  // FC baseline: no posterior
        } else {
          log << report.posterior_mu_rms << "," << report.posterior_sigma;
        }
        log << ",";
        if (std::isfinite(report.validation_posterior_iou)) log << report.validation_posterior_iou;
      }
      log << "\n";
    }
    if ((step + 1) % tc.checkpoint_every == 0) save_checkpoint(step + 1);
    char suffix[160];
    std::snprintf(suffix, sizeof(suffix),
                  " loss %.0f (tsdf %.0f votes %.0f mmd %.2g) val IoU %.3f  %.1f samples/s",
                  recent.back()[0], recent.back()[1], recent.back()[3], recent.back()[4],
                  report.validation_iou, report.samples_per_second);
    bar.update(step + 1, suffix);
  }
  bar.finish();
  finish_worker();
  save_checkpoint(tc.steps);
  report.steps = tc.steps;
  if (trained == 0) {
    // Nothing left to train (a resumed run that had reached its steps): still report the
    // figures of the model being written, from the log and a fresh validation.
    validate(&report);
    std::ifstream previous((out / "train_log.csv").string());
    std::string line, last;
    while (std::getline(previous, line)) {
      if (!line.empty() && std::isdigit(static_cast<unsigned char>(line[0]))) last = line;
    }
    std::array<double, 6> row{};
    double rate = 0.0;
    if (std::sscanf(last.c_str(), "%*[^,],%lf,%lf,%lf,%lf,%lf,%lf,%lf", &row[0], &row[1], &row[2],
                    &row[3], &row[4], &row[5], &rate) == 7) {
      recent.push_back(row);
      report.samples_per_second = rate;
    }
  }
  if (!recent.empty()) {
    std::array<double, 6> mean{};
    for (const auto& a : recent)
      for (size_t i = 0; i < mean.size(); ++i) mean[i] += a[i] / recent.size();
    report.total = mean[0];
    report.tsdf = mean[1];
    report.partial = mean[2];
    report.votes = mean[3];
    report.mmd = mean[4];
    report.occupancy = mean[5];
  }
  // The model file and its provenance.
  YAML::Emitter meta;
  meta << YAML::BeginMap;
  meta << YAML::Key << "command" << YAML::Value << impl_->command_line;
  meta << YAML::Key << "dataset" << YAML::Value << impl_->dataset_path;
  meta << YAML::Key << "dataset_seed" << YAML::Value << impl_->reader->info().seed;
  meta << YAML::Key << "dataset_scenes" << YAML::Value << impl_->reader->size();
  meta << YAML::Key << "validation_scenes" << YAML::Value << tc.validation_scenes;
  meta << YAML::Key << "steps" << YAML::Value << report.steps;
  meta << YAML::Key << "final_losses" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
       << "total" << YAML::Value << report.total << YAML::Key << "tsdf" << YAML::Value
       << report.tsdf << YAML::Key << "partial" << YAML::Value << report.partial << YAML::Key
       << "votes" << YAML::Value << report.votes << YAML::Key << "mmd" << YAML::Value << report.mmd
       << YAML::Key << "occupancy" << YAML::Value << report.occupancy << YAML::EndMap;
  meta << YAML::Key << "validation" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
       << "iou" << YAML::Value << report.validation_iou << YAML::Key << "bce" << YAML::Value
       << report.validation_bce << YAML::Key << "disagreement" << YAML::Value
       << report.validation_disagreement;
  if (std::isfinite(report.validation_posterior_iou))
    meta << YAML::Key << "posterior_code_iou" << YAML::Value << report.validation_posterior_iou;
  meta << YAML::EndMap;
  if (!posterior.empty()) {  // C-VAE steps trained in this run
    meta << YAML::Key << "posterior" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
         << "mu_rms" << YAML::Value << report.posterior_mu_rms << YAML::Key << "sigma"
         << YAML::Value << report.posterior_sigma << YAML::EndMap;
  }
  meta << YAML::Key << "samples_per_second" << YAML::Value << report.samples_per_second;
  meta << YAML::EndMap;
  saveCvae((out / "model.pt").string(), model, meta.c_str());
  std::ofstream yaml((out / "model.yaml").string());
  yaml << "# simstack model provenance (the same config is stored inside model.pt)\nmodel:\n";
  std::istringstream cfg(mc.toYaml());
  for (std::string line; std::getline(cfg, line);) yaml << "  " << line << "\n";
  yaml << "training:\n";
  std::istringstream trn(tc.toYaml());
  for (std::string line; std::getline(trn, line);) yaml << "  " << line << "\n";
  yaml << "provenance:\n";
  std::istringstream m(meta.c_str());
  for (std::string line; std::getline(m, line);) yaml << "  " << line << "\n";
  return report;
}

}  // namespace simstack
