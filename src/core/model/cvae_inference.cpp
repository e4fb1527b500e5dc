#include "simstack/model/cvae_inference.h"

#include <stdexcept>

#include "simstack/model/cvae.h"
#include "simstack/tsdf/network_input.h"

namespace simstack {

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
const std::string& CvaeInference::metadata() const { return impl_->metadata; }

std::vector<CvaePrediction> CvaeInference::predict(const Grid3<float>& partial_tsdf_m,
                                                   const Grid3<float>& weight, int samples,
                                                   uint64_t seed, bool zero_code_first) const {
  const CvaeConfig& c = config();
  const GridSpec& g = partial_tsdf_m.spec;
  if (g.resolution != c.resolution || std::abs(g.extent_m() - c.extent_m) > 1e-9) {
    throw std::invalid_argument("partial TSDF grid is " + std::to_string(g.resolution) +
                                "^3 over " + std::to_string(g.extent_m()) + " m; the model wants " +
                                std::to_string(c.resolution) + "^3 over " +
                                std::to_string(c.extent_m) + " m");
  }
  if (!(weight.spec == g)) throw std::invalid_argument("partial TSDF and weight grids differ");
  if (samples < 1) throw std::invalid_argument("need at least one sample");
  torch::NoGradGuard no_grad;
  // Setting the thread count rebuilds libtorch's thread pool even when the count is unchanged:
  // doing it every frame took 1-6 ms and left the next forward pass 1.6x slower (cold threads).
  if (torch::get_num_threads() != impl_->threads) torch::set_num_threads(impl_->threads);
  const int r = c.resolution;
  const std::vector<float> channels = partialChannels(partial_tsdf_m, weight, c.truncation_m());
  const torch::Tensor one =
      torch::from_blob(const_cast<float*>(channels.data()), {1, 2, r, r, r}).clone();
  torch::Generator gen = at::detail::createCPUGenerator(seed);
  torch::Tensor z = torch::randn({samples, c.latent_size}, gen);
  if (zero_code_first) z[0].zero_();
  // The condition is encoded once and shared by the S codes; the FC baseline has no code and
  // runs once.
  CvaeOutput out = impl_->model->generate(one, c.hasLatentCode() ? z : z.narrow(0, 0, 1));
  if (out.tsdf.size(0) == 1 && samples > 1) {
    out.tsdf = out.tsdf.expand({samples, -1, -1, -1, -1});
    out.votes = out.votes.expand({samples, -1, -1, -1, -1});
  }
  const torch::Tensor tsdf = (out.tsdf * c.truncation_m()).contiguous();
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

}  // namespace simstack
