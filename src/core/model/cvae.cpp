#include "simstack/model/cvae.h"

#include <ATen/ops/mkldnn_convolution.h>

#include <filesystem>
#include <map>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "simstack/model/model_integrity.h"

namespace simstack {
namespace {

const int64_t kFormatVersion = modelFormatVersion();

// A 3D convolution that takes oneDNN's path at inference (see ConvBlock).
torch::Tensor conv3d(torch::nn::Conv3d conv, const torch::Tensor& x, int stride, int padding) {
  if (!torch::GradMode::is_enabled() && x.is_contiguous()) {
    return at::mkldnn_convolution(x, conv->weight, conv->bias, {padding, padding, padding},
                                  {stride, stride, stride}, {1, 1, 1}, 1);
  }
  return conv->forward(x);
}

// Groups of 4 channels (one group when the count is not a multiple of 4): statistics per
// sample, so no sample depends on the rest of its batch.
torch::nn::GroupNorm groupNorm(int channels) {
  return torch::nn::GroupNorm(
      torch::nn::GroupNormOptions(channels % 4 == 0 ? channels / 4 : 1, channels));
}

torch::nn::Conv3d makeConv(int in, int out, int kernel, int stride, bool bias) {
  return torch::nn::Conv3d(
      torch::nn::Conv3dOptions(in, out, kernel).stride(stride).padding(kernel / 2).bias(bias));
}

// oneDNN's convolution with explicit weight and bias (inference only).
torch::Tensor convWith(const torch::Tensor& x, const torch::Tensor& weight,
                       const torch::Tensor& bias, int stride, int padding) {
  return at::mkldnn_convolution(x.contiguous(), weight, bias, {padding, padding, padding},
                                {stride, stride, stride}, {1, 1, 1}, 1);
}

// PReLU with its single slope, in place (inference only): leaky ReLU with that slope.
torch::Tensor preluInPlace(torch::Tensor y, const torch::Tensor& slope) {
  return torch::leaky_relu_(y, slope.item<double>());
}

bool inference(const torch::nn::Module& m) {
  return !m.is_training() && !torch::GradMode::is_enabled();
}

// `weight` with the eval-mode `bn` after it folded in, as {weight, bias}; with `split` > 0 also
// the folded weight's input channels [0, split) and [split, in) (ConvBlockImpl::folded).
std::vector<torch::Tensor> foldBatchNorm(const torch::Tensor& weight,
                                         const torch::nn::BatchNorm3d& bn, int split) {
  torch::NoGradGuard no_grad;
  const torch::Tensor s = bn->weight / torch::sqrt(bn->running_var + bn->options.eps());
  const torch::Tensor w = (weight * s.view({-1, 1, 1, 1, 1})).contiguous();
  std::vector<torch::Tensor> v{w, (bn->bias - bn->running_mean * s).contiguous()};
  if (split > 0) {
    v.push_back(w.narrow(1, 0, split).contiguous());
    v.push_back(w.narrow(1, split, w.size(1) - split).contiguous());
  }
  return v;
}

std::vector<torch::Tensor> bnSources(const torch::Tensor& weight,
                                     const torch::nn::BatchNorm3d& bn) {
  return {weight, bn->weight, bn->bias, bn->running_mean, bn->running_var};
}

}  // namespace

std::vector<torch::Tensor> DerivedWeights::get(
    const std::vector<torch::Tensor>& sources, int variant,
    const std::function<std::vector<torch::Tensor>()>& compute) {
  std::vector<std::pair<const void*, int64_t>> keys;
  keys.reserve(sources.size() + 1);
  for (const torch::Tensor& t : sources) keys.emplace_back(t.data_ptr(), t._version());
  keys.emplace_back(nullptr, variant);
  std::lock_guard<std::mutex> lock(*mutex_);
  if (keys != keys_) {
    values_ = compute();
    keys_ = std::move(keys);
  }
  return values_;
}

ConvBlockImpl::ConvBlockImpl(int in, int out, int stride, bool group_norm) : stride_(stride) {
  conv = register_module("conv", makeConv(in, out, 3, stride, false));
  if (group_norm) {
    gn = register_module("gn", groupNorm(out));
  } else {
    bn = register_module("bn", torch::nn::BatchNorm3d(out));
  }
  act = register_module("act", torch::nn::PReLU());
}

bool ConvBlockImpl::folds() const { return bn && inference(*this); }

std::vector<torch::Tensor> ConvBlockImpl::folded(int split) {
  return folded_.get(bnSources(conv->weight, bn), split,
                     [&] { return foldBatchNorm(conv->weight, bn, split); });
}

torch::Tensor ConvBlockImpl::forward(const torch::Tensor& x) {
  if (folds()) {
    const std::vector<torch::Tensor> f = folded();
    return preluInPlace(convWith(x, f[0], f[1], stride_, 1), act->weight);
  }
  const torch::Tensor y = conv3d(conv, x.contiguous(), stride_, 1);
  return act(bn ? bn(y) : gn(y));
}

ResSEBlockImpl::ResSEBlockImpl(int in, int out, int stride, bool group_norm) {
  a = register_module("a", ConvBlock(in, out, stride, group_norm));
  b = register_module("b", makeConv(out, out, 3, 1, false));
  if (group_norm) {
    gn = register_module("gn", groupNorm(out));
  } else {
    bn = register_module("bn", torch::nn::BatchNorm3d(out));
  }
  const int squeeze = std::max(4, out / 4);
  se1 = register_module("se1", torch::nn::Linear(out, squeeze));
  se2 = register_module("se2", torch::nn::Linear(squeeze, out));
  if (in != out || stride != 1) skip = register_module("skip", makeConv(in, out, 1, stride, false));
  act = register_module("act", torch::nn::PReLU());
}

torch::Tensor ResSEBlockImpl::forward(const torch::Tensor& x) {
  const torch::Tensor shortcut = skip ? conv3d(skip, x.contiguous(), a->stride(), 0) : x;
  return finish(a(x), shortcut);
}

torch::Tensor ResSEBlockImpl::forwardWithCondition(const torch::Tensor& x, const torch::Tensor& c) {
  const int64_t batch = x.size(0);
  if (!a->folds() || !skip || c.size(0) != 1 || batch == 1) {
    return forward(torch::cat({x, c.size(0) == batch ? c : c.expand({batch, -1, -1, -1, -1})}, 1));
  }
  const int split = static_cast<int>(x.size(1));
  const std::vector<torch::Tensor> fa = a->folded(split);
  torch::Tensor y = convWith(x, fa[2], fa[1], a->stride(), 1);
  y.add_(convWith(c, fa[3], {}, a->stride(), 1));
  const std::vector<torch::Tensor> s =
      split_skip_.get({skip->weight}, split, [&]() -> std::vector<torch::Tensor> {
        const torch::Tensor& w = skip->weight;
        return {w.narrow(1, 0, split).contiguous(),
                w.narrow(1, split, w.size(1) - split).contiguous()};
      });
  torch::Tensor shortcut = convWith(x, s[0], {}, a->stride(), 0);
  shortcut.add_(convWith(c, s[1], {}, a->stride(), 0));
  return finish(preluInPlace(y, a->activationWeight()), shortcut);
}

torch::Tensor ResSEBlockImpl::finish(const torch::Tensor& a_out, const torch::Tensor& shortcut) {
  torch::Tensor y;
  if (bn && inference(*this)) {
    const std::vector<torch::Tensor> f =
        folded_b_.get(bnSources(b->weight, bn), 0, [&] { return foldBatchNorm(b->weight, bn, 0); });
    y = convWith(a_out, f[0], f[1], 1, 1);
  } else {
    y = conv3d(b, a_out.contiguous(), 1, 1);
    y = bn ? bn(y) : gn(y);
  }
  // Squeeze: global average; excite: per-channel gates.
  const torch::Tensor gates = torch::sigmoid(se2(torch::relu(se1(y.mean({2, 3, 4})))));
  if (inference(*this)) {
    y.mul_(gates.unsqueeze(2).unsqueeze(3).unsqueeze(4)).add_(shortcut);
    return preluInPlace(y, act->weight);
  }
  y = y * gates.unsqueeze(2).unsqueeze(3).unsqueeze(4);
  return act(y + shortcut);
}

UpsampleImpl::UpsampleImpl(int in, int out) : out_(out) {
  conv = register_module("conv", makeConv(in, 8 * out, 1, 1, true));
}

torch::Tensor UpsampleImpl::forward(const torch::Tensor& x) {
  const auto b = x.size(0), d = x.size(2), h = x.size(3), w = x.size(4);
  const torch::Tensor y = conv3d(conv, x.contiguous(), 1, 0);
  return y.view({b, out_, 2, 2, 2, d, h, w})
      .permute({0, 1, 5, 2, 6, 3, 7, 4})
      .reshape({b, out_, 2 * d, 2 * h, 2 * w});
}

CvaeImpl::CvaeImpl(const CvaeConfig& config) : config_(config) {
  config_.validate();
  const bool gn = config.norm == "group";
  for (int i = 0; i < 5; ++i)
    widths_.push_back(std::min(config.base_channels << i, config.max_channels));
  bottom_ = config.resolution / 16;
  const auto& w = widths_;
  const int flat = w[4] * bottom_ * bottom_ * bottom_;
  // Conditioning autoencoder: 5 convolutions, 2 linear layers each way (Appendix C).
  for (int i = 0; i < 5; ++i) {
    cond_enc_.push_back(
        register_module("cond_enc" + std::to_string(i),
                        ConvBlock(i == 0 ? 2 : w[i - 1], w[i], i == 0 ? 1 : 2, gn)));
  }
  cond_fc1 = register_module("cond_fc1", torch::nn::Linear(flat, config.hidden_size));
  cond_fc2 =
      register_module("cond_fc2", torch::nn::Linear(config.hidden_size, config.condition_size));
  cond_dfc1 =
      register_module("cond_dfc1", torch::nn::Linear(config.condition_size, config.hidden_size));
  cond_dfc2 = register_module("cond_dfc2", torch::nn::Linear(config.hidden_size, flat));
  for (int i = 4; i >= 1; --i) {
    cond_up_.push_back(register_module("cond_up" + std::to_string(i), Upsample(w[i], w[i - 1])));
    cond_dec_.push_back(
        register_module("cond_dec" + std::to_string(i), ConvBlock(w[i - 1], w[i - 1], 1, gn)));
  }
  cond_head = register_module("cond_head", makeConv(w[0], 1, 1, 1, true));
  // Decoder, shared by the C-VAE and the FC baseline. The code's own map to the deepest grid
  // (the FC files hold it unused; "condition" injection has code_fc1/2 in its place).
  if (config.latent_injection != "condition" || !config.hasLatentCode()) {
    dec_fc1 = register_module("dec_fc1", torch::nn::Linear(config.latent_size, config.hidden_size));
    dec_fc2 = register_module("dec_fc2", torch::nn::Linear(config.hidden_size, flat));
  }
  for (int i = 4; i >= 0; --i) {
    if (i < 4)
      dec_up_.push_back(register_module("dec_up" + std::to_string(i), Upsample(w[i + 1], w[i])));
    // Each scale reads the condition's map of that size too, except in the plain FC baseline,
    // which decodes from the deepest map alone.
    const bool skip = i == 4 || config.decoderReadsEveryConditionMap();
    dec_joint_.push_back(register_module("dec_joint" + std::to_string(i),
                                         ResSEBlock((skip ? 2 : 1) * w[i], w[i], 1, gn)));
  }
  head_tsdf = register_module("head_tsdf", ConvBlock(w[0], w[0], 1, gn));
  head_votes = register_module("head_votes", ConvBlock(w[0], w[0], 1, gn));
  out_tsdf = register_module("out_tsdf", makeConv(w[0], 1, 1, 1, true));
  out_votes = register_module("out_votes", makeConv(w[0], 3, 1, 1, true));
  if (config.hasLatentCode()) {
    // Task-specific first layers, then 5 joint residual-SE layers to the latent code.
    enc_tsdf1 = register_module("enc_tsdf1", ConvBlock(1, w[0], 1, gn));
    enc_tsdf2 = register_module("enc_tsdf2", ConvBlock(w[0], w[0], 1, gn));
    enc_votes1 = register_module("enc_votes1", ConvBlock(3, w[0], 1, gn));
    enc_votes2 = register_module("enc_votes2", ConvBlock(w[0], w[0], 1, gn));
    enc_joint_.push_back(register_module("enc_joint0", ResSEBlock(3 * w[0], w[1], 2, gn)));
    for (int i = 1; i < 4; ++i) {
      enc_joint_.push_back(
          register_module("enc_joint" + std::to_string(i), ResSEBlock(2 * w[i], w[i + 1], 2, gn)));
    }
    enc_joint_.push_back(register_module("enc_joint4", ResSEBlock(2 * w[4], w[4], 1, gn)));
    if (config.latent_injection == "every_scale") {
      for (int i = 4; i >= 0; --i) {
        auto proj = register_module("dec_code" + std::to_string(i),
                                    torch::nn::Linear(config.latent_size, w[i]));
        // Small offsets at first, so that a network warm-started from a bottleneck model
        // begins close to it; the gradients still reach the encoder through them.
        torch::NoGradGuard no_grad;
        proj->weight.mul_(0.1);
        proj->bias.zero_();
        dec_code_.push_back(proj);
      }
    }
    if (config.latent_injection == "condition") {
      code_fc1 =
          register_module("code_fc1", torch::nn::Linear(config.latent_size, config.hidden_size));
      code_fc2 = register_module("code_fc2", torch::nn::Linear(config.hidden_size, flat));
      // Zero at first: the code adds nothing until training gives it a use (gradients still
      // reach this layer, and through it, once it moves, the encoder).
      torch::NoGradGuard no_grad;
      code_fc2->weight.zero_();
      code_fc2->bias.zero_();
    }
    enc_mu = register_module("enc_mu", torch::nn::Linear(flat, config.latent_size));
    enc_logvar = register_module("enc_logvar", torch::nn::Linear(flat, config.latent_size));
    if (config.prior == "learned") {
      // From the condition's deepest map; zero at first, so the prior starts as N(0, I) and a
      // warm-started network begins as it was.
      prior_mu = register_module("prior_mu", torch::nn::Linear(flat, config.latent_size));
      prior_logvar = register_module("prior_logvar", torch::nn::Linear(flat, config.latent_size));
      torch::NoGradGuard no_grad;
      for (auto* l : {&prior_mu, &prior_logvar}) {
        (*l)->weight.zero_();
        (*l)->bias.zero_();
      }
    }
  }
}

void CvaeImpl::setConfig(const CvaeConfig& config) {
  CvaeConfig network = config_;
  network.copyLossSettings(config);
  if (network.toYaml() != config.toYaml())
    throw std::invalid_argument("setConfig: the config describes another network");
  config.validate();
  config_ = config;
}

std::vector<torch::Tensor> CvaeImpl::encodeCondition(const torch::Tensor& partial) {
  std::vector<torch::Tensor> features;
  torch::Tensor x = partial;
  for (auto& block : cond_enc_) {
    x = block(x);
    features.push_back(x);
  }
  if (config_.hidden_condition == "coarse") {
    // Channel 1 is the observed mask; a 16^3 cell counts as observed when any voxel in it is.
    const torch::Tensor observed = partial.narrow(1, 1, 1);
    features[0] = features[0] * observed;
    features[1] = features[1] * torch::max_pool3d(observed, 2);
  }
  return features;
}

torch::Tensor CvaeImpl::decodeCondition(const torch::Tensor& deepest) {
  const auto b = deepest.size(0);
  torch::Tensor x = cond_fc2(torch::relu(cond_fc1(deepest.flatten(1))));
  x = cond_dfc2(torch::relu(cond_dfc1(x))).view({b, widths_[4], bottom_, bottom_, bottom_});
  for (size_t i = 0; i < cond_up_.size(); ++i) x = cond_dec_[i](cond_up_[i](x));
  return torch::tanh(conv3d(cond_head, x.contiguous(), 1, 0));
}

CvaeOutput CvaeImpl::decode(const torch::Tensor& bottleneck, const std::vector<torch::Tensor>& cond,
                            const torch::Tensor& z) {
  torch::Tensor x = bottleneck;
  torch::Tensor keep;  // per sample: 1 keeps the two finest condition maps, 0 drops them
  if (is_training() && config_.condition_dropout > 0.0) {
    keep = (torch::rand({x.size(0), 1, 1, 1, 1}, x.options()) >= config_.condition_dropout)
               .to(x.dtype());
  }
  for (int level = 4, k = 0; level >= 0; --level, ++k) {
    if (level < 4) x = dec_up_[k - 1](x);
    if (!dec_code_.empty() && z.defined()) x = x + dec_code_[k](z).view({z.size(0), -1, 1, 1, 1});
    if (level < 4 && !config_.decoderReadsEveryConditionMap()) {
      x = dec_joint_[k](x);
      continue;
    }
    const torch::Tensor c = keep.defined() && level <= 1 ? cond[level] * keep : cond[level];
    x = dec_joint_[k]->forwardWithCondition(x, c);
  }
  CvaeOutput out;
  if (head_tsdf->folds()) {
    // The two task heads read the same map: one convolution to both heads' channels (oneDNN
    // fills its 16-channel blocks instead of two half-empty ones), each head's PReLU slope on
    // its channels, and one 1x1 convolution whose block-diagonal weight gives both outputs.
    const std::vector<torch::Tensor> ft = head_tsdf->folded(), fv = head_votes->folded();
    const int64_t n = ft[0].size(0);
    // {3x3x3 weight, bias, 1x1 weight, bias}, made again only when a tensor they come from
    // changes.
    const std::vector<torch::Tensor> f =
        heads_.get({ft[0], ft[1], fv[0], fv[1], out_tsdf->weight, out_tsdf->bias, out_votes->weight,
                    out_votes->bias},
                   0, [&]() -> std::vector<torch::Tensor> {
                     torch::NoGradGuard no_grad;
                     torch::Tensor w = torch::zeros({4, 2 * n, 1, 1, 1}, ft[0].options());
                     w.narrow(0, 0, 1).narrow(1, 0, n).copy_(out_tsdf->weight);
                     w.narrow(0, 1, 3).narrow(1, n, n).copy_(out_votes->weight);
                     // The folded tensors stay with their products: a new fold then cannot
                     // reuse the storage address this cache is keyed on.
                     return {torch::cat({ft[0], fv[0]}).contiguous(),
                             torch::cat({ft[1], fv[1]}),
                             w,
                             torch::cat({out_tsdf->bias, out_votes->bias}),
                             ft[0],
                             ft[1],
                             fv[0],
                             fv[1]};
                   });
    const torch::Tensor h = convWith(x, f[0], f[1], 1, 1);
    // Each head's PReLU has one slope: leaky ReLU with it, in place on that head's channels.
    preluInPlace(h.narrow(1, 0, n), head_tsdf->activationWeight());
    preluInPlace(h.narrow(1, n, n), head_votes->activationWeight());
    const torch::Tensor o = convWith(h, f[2], f[3], 1, 0);
    out.tsdf = torch::tanh(o.narrow(1, 0, 1));
    out.votes = o.narrow(1, 1, 3);
    return out;
  }
  out.tsdf = torch::tanh(conv3d(out_tsdf, head_tsdf(x).contiguous(), 1, 0));
  out.votes = conv3d(out_votes, head_votes(x).contiguous(), 1, 0);
  return out;
}

std::pair<torch::Tensor, torch::Tensor> CvaeImpl::encodePosterior(
    const std::vector<torch::Tensor>& cond, const torch::Tensor& tsdf, const torch::Tensor& votes) {
  torch::Tensor x =
      torch::cat({enc_tsdf2(enc_tsdf1(tsdf)), enc_votes2(enc_votes1(votes)), cond[0]}, 1);
  for (int i = 0; i < 5; ++i) {
    x = enc_joint_[i](x);
    if (i < 4) x = torch::cat({x, cond[i + 1]}, 1);
  }
  return {enc_mu(x.flatten(1)), enc_logvar(x.flatten(1)).clamp(-10.0, 10.0)};
}

torch::Tensor CvaeImpl::posteriorMean(const torch::Tensor& partial, const torch::Tensor& tsdf,
                                      const torch::Tensor& votes) {
  if (!config_.hasLatentCode()) throw std::invalid_argument("posteriorMean: the model has no code");
  return encodePosterior(encodeCondition(partial), tsdf, votes).first;
}

CvaeOutput CvaeImpl::forward(const torch::Tensor& partial, const torch::Tensor& tsdf,
                             const torch::Tensor& votes) {
  const std::vector<torch::Tensor> cond = encodeCondition(partial);
  const torch::Tensor partial_recon = decodeCondition(cond[4]);
  if (!config_.hasLatentCode()) {
    CvaeOutput out = decode(cond[4], cond);
    out.partial_recon = partial_recon;
    return out;
  }
  const auto [mu, logvar] = encodePosterior(cond, tsdf, votes);
  // best_of codes per scene, scene-major (scene i's are rows i k ... i k + k - 1).
  const int64_t k = is_training() ? config_.best_of : 1;
  std::vector<torch::Tensor> decode_cond = cond;
  if (k > 1)
    for (torch::Tensor& t : decode_cond) t = t.repeat_interleave(k, 0);
  const torch::Tensor m = mu.repeat_interleave(k, 0), lv = logvar.repeat_interleave(k, 0);
  const torch::Tensor z =
      config_.posterior == "deterministic" ? m : m + torch::randn_like(m) * torch::exp(0.5 * lv);
  CvaeOutput out = decodeWith(decode_cond, z);
  out.partial_recon = partial_recon;
  out.mu = mu;
  out.logvar = logvar;
  if (prior_mu) std::tie(out.prior_mu, out.prior_logvar) = priorOf(cond);
  return out;
}

std::pair<torch::Tensor, torch::Tensor> CvaeImpl::priorOf(const std::vector<torch::Tensor>& cond) {
  const torch::Tensor deepest = cond[4].flatten(1);
  return {prior_mu(deepest), prior_logvar(deepest).clamp(-10.0, 10.0)};
}

CvaeOutput CvaeImpl::decodeWith(const std::vector<torch::Tensor>& cond, const torch::Tensor& z) {
  if (!config_.hasLatentCode()) return decode(cond[4], cond);
  const auto b = z.size(0);
  // One condition for all codes is encoded once; the decoder's blocks share its features.
  if (cond[0].size(0) != 1 && cond[0].size(0) != b) {
    throw std::invalid_argument("generate: " + std::to_string(cond[0].size(0)) +
                                " conditions for " + std::to_string(b) + " codes");
  }
  const std::vector<int64_t> shape{b, widths_[4], bottom_, bottom_, bottom_};
  const torch::Tensor bottleneck = code_fc2
                                       ? cond[4] + code_fc2(torch::relu(code_fc1(z))).view(shape)
                                       : dec_fc2(torch::relu(dec_fc1(z))).view(shape);
  CvaeOutput out = decode(bottleneck, cond, z);
  out.z = z;
  return out;
}

CvaeOutput CvaeImpl::decodeCodes(const torch::Tensor& partial, const torch::Tensor& z) {
  return decodeWith(encodeCondition(partial), z);
}

CvaeOutput CvaeImpl::generate(const torch::Tensor& partial, const torch::Tensor& z) {
  return generateFrom(encodeCondition(partial), z);
}

CvaeOutput CvaeImpl::generateFrom(const std::vector<torch::Tensor>& cond, const torch::Tensor& z) {
  if (!prior_mu || !config_.hasLatentCode()) return decodeWith(cond, z);
  const auto [mean, logvar] = priorOf(cond);
  return decodeWith(cond, mean + torch::exp(0.5 * logvar) * z);
}

std::map<std::string, torch::Tensor> cvaeTensors(Cvae& model) {
  std::map<std::string, torch::Tensor> out;
  for (const auto& p : model->named_parameters()) out[p.key()] = p.value();
  for (const auto& b : model->named_buffers()) out[b.key()] = b.value();
  return out;
}

Cvae loadCvae(const std::string& path, const CvaeConfig* expect, std::string* metadata) {
  if (path.empty()) throw std::runtime_error("no model file named (model_path is empty)");
  if (!std::filesystem::exists(path)) throw std::runtime_error("model file not found: " + path);
  verifyModelFile(path);  // the card's SHA-256 and format, before a damaged file is parsed
  torch::serialize::InputArchive archive;
  try {
    archive.load_from(path);
  } catch (const c10::Error& e) {
    throw std::runtime_error("model file " + path +
                             " is not a libtorch archive (corrupt or wrong file)");
  }
  torch::IValue format, yaml, meta;
  if (!archive.try_read("simstack_format", format) || !archive.try_read("simstack_config", yaml)) {
    throw std::runtime_error("model file " + path +
                             " is not a simstack model (no simstack_config)");
  }
  if (!format.isInt() || !yaml.isString())
    throw std::runtime_error("model file " + path +
                             " is not a simstack model (simstack_format is not an integer or "
                             "simstack_config not a string)");
  if (format.toInt() != kFormatVersion) {
    throw std::runtime_error("model file " + path + " has format " +
                             std::to_string(format.toInt()) + ", this build reads " +
                             std::to_string(kFormatVersion));
  }
  CvaeConfig config;
  try {
    config = CvaeConfig::fromYaml(yaml.toStringRef());
  } catch (const std::invalid_argument& e) {
    throw std::runtime_error("model file " + path + ": invalid config: " + e.what());
  }
  if (expect) {
    auto mismatch = [&](const std::string& field, const std::string& a, const std::string& b) {
      throw std::runtime_error("model file " + path + ": " + field + " is " + a + " but " + b +
                               " was expected");
    };
    if (config.resolution != expect->resolution)
      mismatch("resolution", std::to_string(config.resolution), std::to_string(expect->resolution));
    if (config.architecture != expect->architecture)
      mismatch("architecture", config.architecture, expect->architecture);
    if (std::abs(config.extent_m - expect->extent_m) > 1e-9)
      mismatch("extent_m", std::to_string(config.extent_m), std::to_string(expect->extent_m));
  }
  Cvae model(config);
  // Module::load takes each stored tensor as it is, whatever its shape: compare with the shapes
  // the config builds, so that a mismatched file fails here and not in the first forward pass.
  std::map<std::string, std::vector<int64_t>> built;
  for (const auto& [name, t] : cvaeTensors(model)) built[name] = t.sizes().vec();
  try {
    model->load(archive);
  } catch (const c10::Error& e) {
    throw std::runtime_error("model file " + path +
                             ": weights do not match its config: " + e.what_without_backtrace());
  }
  for (const auto& [name, t] : cvaeTensors(model))
    if (t.sizes().vec() != built.at(name))
      throw std::runtime_error("model file " + path + ": tensor " + name + " has shape " +
                               c10::str(t.sizes()) + " but its config builds " +
                               c10::str(c10::IntArrayRef(built.at(name))));
  // A weight that is NaN or infinite makes every output NaN: the network would see nothing.
  for (const auto& [name, t] : cvaeTensors(model))
    if (t.is_floating_point() && !torch::isfinite(t).all().item<bool>())
      throw std::runtime_error("model file " + path + ": tensor " + name +
                               " holds values that are not finite (NaN or infinite): the file is "
                               "damaged");
  if (metadata && archive.try_read("simstack_metadata", meta)) {
    if (!meta.isString())
      throw std::runtime_error("model file " + path + ": simstack_metadata is not a string");
    *metadata = meta.toStringRef();
  }
  return model;
}

}  // namespace simstack
