#pragma once
/// @file cli_checks.h
/// Number checks for the tools' options whose messages a person can read: CLI11's
/// PositiveNumber answers "0" with "Value 0 not in range 0.000000 to 1797...(300 digits)" and
/// lets "nan" and "inf" through.

#include <CLI/CLI.hpp>

#include <cmath>
#include <exception>
#include <string>

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

}  // namespace simstack
