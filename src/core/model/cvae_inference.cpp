#include "simstack/model/cvae_inference.h"

#include <algorithm>
#include <chrono>
#include <limits>
#include <map>
#include <stdexcept>

#include "simstack/model/cvae.h"
#include "simstack/tsdf/network_input.h"

namespace simstack {

namespace {

/// Network outputs [S, ...] as predictions on grid g.
std::vector<CvaePrediction> toPredictions(const CvaeOutput& out, const GridSpec& g, int samples,
                                          double truncation_m) {
  const torch::Tensor tsdf = (out.tsdf * truncation_m).contiguous();
  const torch::Tensor votes = out.votes.contiguous();
  std::vector<CvaePrediction> result(samples);
  const size_t n = static_cast<size_t>(g.voxelCount());
  for (int s = 0; s < samples; ++s) {
    result[s].tsdf_m = Grid3<float>(g, 0.0f);
    result[s].votes = Grid3<Vec3f>(g, Vec3f::Zero());
    const float* t = tsdf.data_ptr<float>() + s * n;
    std::copy(t, t + n, result[s].tsdf_m.data.begin());
    const float* v = votes.data_ptr<float>() + s * 3 * n;
    for (size_t i = 0; i < n; ++i) result[s].votes.data[i] = Vec3f(v[i], v[n + i], v[2 * n + i]);
  }
  return result;
}

/// One of the 8 symmetries of the grid's square cross-section (bit 0: swap x and y, bit 1:
/// mirror x, bit 2: mirror y; 3, 6 and 5 are the quarter, half and three-quarter turns about
/// the vertical), on a [B, C, z, y, x] tensor; with `vector` the channels are a vector field
/// (x, y, z) whose components turn with it. `inverse` undoes it.
torch::Tensor symmetry(torch::Tensor t, int which, bool vector, bool inverse) {
  auto swap = [&](torch::Tensor a) {
    a = a.transpose(3, 4);
    return vector ? torch::cat({a.narrow(1, 1, 1), a.narrow(1, 0, 1), a.narrow(1, 2, 1)}, 1) : a;
  };
  auto mirror = [&](torch::Tensor a, int dim, int component) {
    a = a.flip({dim});
    if (vector) a.narrow(1, component, 1).neg_();  // flip() returned a copy
    return a;
  };
  if (!inverse && (which & 1)) t = swap(t);
  if (which & 2) t = mirror(t, 4, 0);
  if (which & 4) t = mirror(t, 3, 1);
  if (inverse && (which & 1)) t = swap(t);
  return t.contiguous();
}

/// The symmetries (symmetry()'s `which`) averaged for each allowed count; each set is a group,
/// so that the average turns with the pile.
const std::map<int, std::vector<int>> kSymmetryGroups = {
    {1, {0}}, {2, {0, 6}}, {4, {0, 3, 6, 5}}, {8, {0, 1, 2, 3, 4, 5, 6, 7}}};

/// The condition `one` [1, ...] encoded as seen and turned by each symmetry of the group for
/// `symmetries` (kSymmetryGroups), in the group's order.
std::vector<std::vector<torch::Tensor>> encodeSymmetric(Cvae& model, const torch::Tensor& one,
                                                        int symmetries) {
  std::vector<std::vector<torch::Tensor>> conds;
  for (int which : kSymmetryGroups.at(symmetries))
    conds.push_back(model->encodeCondition(which == 0 ? one : symmetry(one, which, false, false)));
  return conds;
}

/// The network's outputs for codes `z` and the encoded conditions of encodeSymmetric(),
/// averaged over the group: each output turned back. A pile turned about the vertical or
/// mirrored is as plausible as the pile itself, so the errors of the passes partly cancel.
CvaeOutput generateSymmetric(Cvae& model, const std::vector<std::vector<torch::Tensor>>& conds,
                             const torch::Tensor& z, int symmetries) {
  const std::vector<int>& group = kSymmetryGroups.at(symmetries);
  CvaeOutput out = model->generateFrom(conds[0], z);
  if (symmetries == 1) return out;
  for (size_t k = 1; k < group.size(); ++k) {
    const CvaeOutput o = model->generateFrom(conds[k], z);
    out.tsdf = out.tsdf + symmetry(o.tsdf, group[k], false, true);
    out.votes = out.votes + symmetry(o.votes, group[k], true, true);
  }
  out.tsdf = out.tsdf / symmetries;
  out.votes = out.votes / symmetries;
  return out;
}

torch::Tensor gridTensor(const std::vector<float>& values, int r) {
  return torch::from_blob(const_cast<float*>(values.data()), {1, 1, r, r, r}).clone();
}

/// The `samples` codes of `z` [M, L] with the lowest `loss` [M], best first.
torch::Tensor bestCodes(const torch::Tensor& z, const torch::Tensor& loss, int samples) {
  return z.index_select(0, std::get<1>(loss.topk(samples, 0, /*largest=*/false))).clone();
}

}  // namespace

struct CvaeInference::Impl {
  Cvae model{nullptr};
  std::string metadata;
  int threads = 2;
};

CvaeInference::CvaeInference(const std::string& path, int threads)
    : impl_(std::make_unique<Impl>()) {
  impl_->model = loadCvae(path, nullptr, &impl_->metadata);
  impl_->model->eval();
  impl_->threads = threads;
}

CvaeInference::~CvaeInference() = default;

const CvaeConfig& CvaeInference::config() const { return impl_->model->config(); }

void CvaeInference::checkInput(const Grid3<float>& partial_tsdf_m, const Grid3<float>& weight,
                               int samples) const {
  const CvaeConfig& c = config();
  const GridSpec& g = partial_tsdf_m.spec;
  if (g.resolution != c.resolution) {
    throw std::invalid_argument("partial TSDF grid is " + std::to_string(g.resolution) +
                                "^3; the model wants " + std::to_string(c.resolution) + "^3");
  }
  if (!(weight.spec == g)) throw std::invalid_argument("partial TSDF and weight grids differ");
  if (samples < 1) throw std::invalid_argument("need at least one sample");
  // Setting the thread count rebuilds libtorch's thread pool even when the count is unchanged,
  // and the next forward pass then runs on cold threads: only a change is set
  // (docs/benchmarks.md).
  if (torch::get_num_threads() != impl_->threads) torch::set_num_threads(impl_->threads);
}

void validateSymmetries(int symmetries) {
  if (!kSymmetryGroups.count(symmetries))
    throw std::invalid_argument("symmetries must be 1, 2, 4 or 8, not " +
                                std::to_string(symmetries));
}

void validateRefineOptions(const RefineOptions& options) {
  if (options.iterations < 0 || !(options.learning_rate > 0) || !(options.prior_weight >= 0) ||
      options.starts < 0)
    throw std::invalid_argument(
        "refine: iterations, prior_weight and starts must be >= 0 and learning_rate > 0");
  if (options.evidence != "tsdf" && options.evidence != "sign")
    throw std::invalid_argument("refine: evidence must be 'tsdf' or 'sign', not '" +
                                options.evidence + "'");
  validateSymmetries(options.symmetries);
}

const std::string& CvaeInference::metadata() const { return impl_->metadata; }

std::vector<CvaePrediction> CvaeInference::predict(const Grid3<float>& partial_tsdf_m,
                                                   const Grid3<float>& weight, int samples,
                                                   uint64_t seed, bool zero_code_first,
                                                   int symmetries) const {
  const CvaeConfig& c = config();
  const GridSpec& g = partial_tsdf_m.spec;
  checkInput(partial_tsdf_m, weight, samples);
  validateSymmetries(symmetries);
  torch::NoGradGuard no_grad;
  const int r = c.resolution;
  const double tau = truncationIn(c, g);
  const std::vector<float> channels = partialChannels(partial_tsdf_m, weight, tau);
  const torch::Tensor one =
      torch::from_blob(const_cast<float*>(channels.data()), {1, 2, r, r, r}).clone();
  torch::Generator gen = at::detail::createCPUGenerator(seed);
  torch::Tensor z = torch::randn({samples, c.latent_size}, gen);
  if (zero_code_first) z[0].zero_();
  // The condition is encoded once and shared by the S codes; the FC baseline has no code and
  // runs once.
  CvaeOutput out = generateSymmetric(impl_->model, encodeSymmetric(impl_->model, one, symmetries),
                                     c.hasLatentCode() ? z : z.narrow(0, 0, 1), symmetries);
  if (out.tsdf.size(0) == 1 && samples > 1) {
    out.tsdf = out.tsdf.expand({samples, -1, -1, -1, -1});
    out.votes = out.votes.expand({samples, -1, -1, -1, -1});
  }
  return toPredictions(out, g, samples, tau);
}

std::vector<CvaePrediction> CvaeInference::refine(const Grid3<float>& partial_tsdf_m,
                                                  const Grid3<float>& weight,
                                                  const std::vector<ViewEvidence>& views,
                                                  int samples, uint64_t seed, bool zero_code_first,
                                                  const RefineOptions& options,
                                                  RefineReport* report) const {
  const CvaeConfig& c = config();
  const GridSpec& g = partial_tsdf_m.spec;
  for (const ViewEvidence& v : views)
    if (!(v.tsdf_m.spec == g) || !(v.weight.spec == g))
      throw std::invalid_argument("refine: every view's TSDF must lie on the prediction's grid");
  validateRefineOptions(options);
  if (!c.hasLatentCode() || views.empty() || (options.iterations == 0 && options.starts <= samples))
    return predict(partial_tsdf_m, weight, samples, seed, zero_code_first, options.symmetries);
  checkInput(partial_tsdf_m, weight, samples);
  if (report) *report = RefineReport{};  // a reused report starts afresh
  const auto start = std::chrono::steady_clock::now();
  torch::AutoGradMode grad_mode(true);  // also when the caller turned gradients off
  const int r = c.resolution;
  const double tau = truncationIn(c, g);
  const std::vector<float> channels = partialChannels(partial_tsdf_m, weight, tau);
  const torch::Tensor one =
      torch::from_blob(const_cast<float*>(channels.data()), {1, 2, r, r, r}).clone();
  // Targets in units of tau, and where each view observed the scene.
  std::vector<torch::Tensor> target, observed;
  for (const ViewEvidence& v : views) {
    target.push_back((gridTensor(v.tsdf_m.data, r) / tau).clamp(-1.0, 1.0));
    observed.push_back((gridTensor(v.weight.data, r) > 0).to(torch::kFloat));
  }
  const bool sign_evidence = options.evidence == "sign";
  auto lossOf = [&](const torch::Tensor& tsdf, const torch::Tensor& z) {  // per code [S]
    torch::Tensor sum = torch::zeros({tsdf.size(0)});
    for (size_t k = 0; k < target.size(); ++k) {
      const torch::Tensor miss =
          sign_evidence ? (-tsdf * target[k]).clamp_min(0.0) : (tsdf - target[k]).abs();
      sum = sum + (miss * observed[k]).flatten(1).sum(1);
    }
    return sum / static_cast<double>(target.size()) + options.prior_weight * 0.5 * z.pow(2).sum(1);
  };
  torch::Generator gen = at::detail::createCPUGenerator(seed);
  torch::Tensor z = torch::randn({std::max(samples, options.starts), c.latent_size}, gen);
  if (zero_code_first) z[0].zero_();
  // The condition does not change: encoded once (each pass's), without a graph. The codes
  // are scored on the plain pass, or on the passes' average.
  const int fit_passes = options.fit_on_passes ? options.symmetries : 1;
  std::vector<std::vector<torch::Tensor>> conds;
  {
    torch::NoGradGuard no_grad;
    conds = encodeSymmetric(impl_->model, one, options.symmetries);
    if (z.size(0) > samples) {
      const torch::Tensor loss =
          lossOf(generateSymmetric(impl_->model, conds, z, fit_passes).tsdf, z);
      if (report)
        report->start_loss.assign(loss.data_ptr<float>(), loss.data_ptr<float>() + loss.size(0));
      z = bestCodes(z, loss, samples);
    }
  }
  z.set_requires_grad(true);
  torch::optim::Adam adam({z}, torch::optim::AdamOptions(options.learning_rate));
  // The best code of each start so far (the loss may rise again after a step).
  torch::Tensor best_z = z.detach().clone();
  torch::Tensor best_loss = torch::full({samples}, std::numeric_limits<float>::infinity());
  for (int it = 0; it <= options.iterations; ++it) {
    const torch::Tensor loss =
        lossOf(generateSymmetric(impl_->model, conds, z, fit_passes).tsdf, z);
    {
      torch::NoGradGuard no_grad;
      const torch::Tensor better = loss.detach() < best_loss;
      best_loss = torch::where(better, loss.detach(), best_loss);
      best_z = torch::where(better.unsqueeze(1), z.detach(), best_z);
    }
    if (report) report->loss.push_back(best_loss.min().item<double>());
    if (it == options.iterations) break;
    // The gradient of the codes alone: the network's weights get none (they are shared, and
    // their gradients would cost a backward pass through every layer's weights).
    z.mutable_grad() = torch::autograd::grad({loss.sum()}, {z})[0];
    adam.step();
  }
  torch::NoGradGuard no_grad;
  const CvaeOutput out = generateSymmetric(impl_->model, conds, best_z, options.symmetries);
  if (report) {
    report->code_loss.assign(best_loss.data_ptr<float>(), best_loss.data_ptr<float>() + samples);
    report->ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  }
  return toPredictions(out, g, samples, tau);
}

}  // namespace simstack
