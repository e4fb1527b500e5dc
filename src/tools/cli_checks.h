#pragma once
/// @file cli_checks.h
/// Number checks for the tools' options whose messages a person can read: CLI11's
/// PositiveNumber answers "0" with "Value 0 not in range 0.000000 to 1797...(300 digits)" and
/// lets "nan" and "inf" through.

#include <CLI/CLI.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <exception>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "simstack/io/staged_output.h"

namespace simstack {

/// A finite number that `ok` accepts; otherwise "'TEXT' is not a finite number WHAT".
inline CLI::Validator finiteNumber(bool (*ok)(double), const std::string& what,
                                   const std::string& name) {
  return CLI::Validator(
      [ok, what](std::string& text) -> std::string {
        try {
          size_t used = 0;
          const double v = std::stod(text, &used);
          if (used == text.size() && std::isfinite(v) && ok(v)) return {};
        } catch (const std::exception&) {
        }
        return "'" + text + "' is not a finite number " + what;
      },
      name);
}

/// A finite number > 0.
inline const CLI::Validator FinitePositive =
    finiteNumber([](double v) { return v > 0.0; }, "> 0", "FINITE>0");
/// A finite number >= 0.
inline const CLI::Validator FiniteNonNegative =
    finiteNumber([](double v) { return v >= 0.0; }, ">= 0", "FINITE>=0");

/// A seed: a whole number >= 0 (CLI11 reads "-1" into an unsigned as 2^64 - 1), given as
/// ->transform(SeedNumber); readIntegersInDecimal drops its leading zeros first.
inline const CLI::Validator SeedNumber(
    [](std::string& text) -> std::string {
      // Up to 2^64 - 1: a larger one would be clamped, two seeds giving the same data.
      const std::string largest = "18446744073709551615";
      const std::string digits = text.substr(std::min(text.find_first_not_of('0'), text.size()));
      if (!text.empty() && text.find_first_not_of("0123456789") == std::string::npos &&
          (digits.size() < largest.size() ||
           (digits.size() == largest.size() && digits <= largest))) {
        return {};
      }
      return "'" + text.substr(0, 40) + "' is not a seed (a whole number from 0 to " + largest +
             ")";
    },
    "SEED");

/// A whole number as a person writes it: "010" is ten and "-07" minus seven, where CLI11 would
/// read a leading 0 as octal; "0x10" and "0b1" are refused. The sign is left to the option's own
/// checks (SeedNumber for an unsigned one, which CLI11 would wrap from -1 to 2^64 - 1).
inline const CLI::Validator DecimalInteger(
    [](std::string& text) -> std::string {
      const size_t signs = !text.empty() && (text[0] == '-' || text[0] == '+');
      const std::string body = text.substr(signs);
      if (body.empty() || body.find_first_not_of("0123456789") != std::string::npos) {
        if (body.size() > 1 && body[0] == '0' && std::isalpha(static_cast<unsigned char>(body[1])))
          return "'" + text.substr(0, 40) + "' is not a whole number in decimal";
        return {};  // not a number at all: CLI11's conversion names it
      }
      const std::string digits = body.substr(std::min(body.find_first_not_of('0'), body.size()));
      text = digits.empty() ? "0" : text.substr(0, signs) + digits;
      return {};
    },
    "");

/// Gives every integer option of `app` DecimalInteger, ahead of its own checks: call it after
/// the last add_option, before parsing.
inline void readIntegersInDecimal(CLI::App& app) {
  for (CLI::Option* option : app.get_options()) {
    const std::string type = option->get_type_name();
    if (type.rfind("INT", 0) == 0 || type.rfind("UINT", 0) == 0) option->transform(DecimalInteger);
  }
}

/// A path to write: not empty, no control characters, names within the file system's limits
/// (unwritablePath).
inline const CLI::Validator WritablePath(
    [](std::string& text) -> std::string {
      const std::string why = unwritablePath(text);
      return why.empty() ? std::string() : "'" + text.substr(0, 80) + "': " + why;
    },
    "PATH");

/// Throws std::runtime_error when the file `output` (given as `option`) would replace one of
/// `inputs`, by the same or another name (a link, "./", ".."): an evaluation's --output naming
/// its --dataset would otherwise put its results where the test piles were. Empty names are
/// skipped. `what` names the others in the message ("the input file", "the --output file").
inline void requireNotAnInput(const std::string& option, const std::string& output,
                              const std::vector<std::string>& inputs,
                              const std::string& what = "the input file") {
  namespace fs = std::filesystem;
  if (output.empty()) return;
  // Absolute first: weakly_canonical keeps a relative name none of whose parts exists as it
  // is ("a.json"), but makes one with an existing part absolute ("./a.json").
  const auto normal = [](const std::string& p, std::error_code& ec) {
    const fs::path absolute = fs::absolute(p, ec);
    if (ec) return absolute;
    return fs::weakly_canonical(absolute, ec);
  };
  std::error_code ec;
  const fs::path out = normal(output, ec);
  for (const std::string& input : inputs) {
    if (input.empty()) continue;
    std::error_code ec_in;
    const bool same = fs::exists(output) && fs::exists(input) ? fs::equivalent(output, input, ec_in)
                                                              : !ec && out == normal(input, ec_in);
    if (same && !ec_in)
      throw std::runtime_error(option + " " + output + " is " + what + " " + input +
                               ", which it would replace: give another path");
  }
}

}  // namespace simstack
