#pragma once
/// @file model_writer.h
/// Model files as the trainer writes them (the runtime reads them with loadCvae), and the
/// warm start of a new network from an older file.

#include <torch/torch.h>

#include <functional>
#include <string>
#include <vector>

#include "simstack/model/cvae.h"

namespace simstack {

/// Saves weights, buffers and the config (YAML) in one archive, plus `metadata` YAML text and
/// whatever `extra` writes into the same archive (the trainer's checkpoint: optimizer and step).
/// Written beside `path` and renamed into it: the file is whole or absent.
void saveCvae(const std::string& path, Cvae& model, const std::string& metadata = "",
              const std::function<void(torch::serialize::OutputArchive&)>& extra = {});

/// Warm start: copies into `model` every parameter and buffer of the model file `path` that has
/// the same name and shape, and returns the names of `model`'s tensors left as they were (new
/// in this network). Throws std::runtime_error naming the file and the tensor when a tensor of
/// the same name has another shape, or when the file shares no tensor with `model`.
std::vector<std::string> warmStartCvae(Cvae& model, const std::string& path);

}  // namespace simstack
