#pragma once
/// @file
/// JSON from a user's file, bounded and checked as it is parsed (issue #44): nesting at most
/// `Limits().max_json_depth`, at most `Limits().max_json_values` values (so the parsed document's
/// memory is bounded whatever the text), and a key given twice in one object is an error naming
/// its path (a duplicate `plans` would otherwise silently replace the first). Every reader of a
/// plan, scene, markups, label-map or bench file parses through here.

#include <cstdint>
#include <string>

#include <nlohmann/json.hpp>

namespace trocar {

/// Parses `text` read from `where` (a path, for messages); `kind` names what the file should be
/// in the message when the text is not JSON ("<where>: not <kind> (JSON: ...)").
/// @throws trocar::Error naming `where`, and the path in the document (e.g. `plans[0].ports`)
///         where one applies: not JSON, nested too deep, too many values, a repeated key.
nlohmann::json ParseJsonText(const std::string& text, const std::string& where,
                             const std::string& kind = "valid JSON");

/// ReadTextFile (bounded by Limits().max_text_bytes) then ParseJsonText.
nlohmann::json ReadJsonFile(const std::string& path, const std::string& kind = "valid JSON");

/// An integer field as `int`, range-checked before any narrowing (4294967298 is not 2).
/// @throws trocar::Error naming `where` and `field` when it is not an integer in [lo, hi].
int JsonInt(const nlohmann::json& value, const std::string& where, const std::string& field,
            std::int64_t lo = INT32_MIN, std::int64_t hi = INT32_MAX);

}  // namespace trocar
