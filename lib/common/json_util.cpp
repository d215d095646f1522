#include "common/json_util.hpp"

#include <unordered_set>
#include <vector>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/limits.hpp"

namespace trocar {
namespace {

using nlohmann::json;

// One open object or array while parsing: its path, and for an object the keys seen and the
// current key, for an array the index of the next element.
struct Open {
  bool array = false;
  std::string path;
  std::size_t next = 0;
  std::string key;
  std::unordered_set<std::string> keys;
};

std::string ChildPath(const std::vector<Open>& open) {
  if (open.empty()) return "";
  const Open& top = open.back();
  if (top.array) return top.path + "[" + std::to_string(top.next) + "]";
  return top.path.empty() ? top.key : top.path + "." + top.key;
}

}  // namespace

json ParseJsonText(const std::string& text, const std::string& where, const std::string& kind) {
  const InputLimits& limits = Limits();
  std::vector<Open> open;
  std::uint64_t values = 0;
  auto counted = [&](const std::string& at) {
    if (++values > limits.max_json_values) {
      TROCAR_THROW(where << ": " << (at.empty() ? "the document" : at) << ": more than "
                         << limits.max_json_values << " JSON values "
                         << LimitHint(limits.max_json_values, "TROCAR_MAX_JSON_VALUES"));
    }
  };
  auto bounded_string = [&](const json& parsed, const std::string& at) {
    if (parsed.is_string() && parsed.get_ref<const std::string&>().size() > limits.max_json_string) {
      TROCAR_THROW(where << ": " << (at.empty() ? "the document" : at) << ": a string of "
                         << parsed.get_ref<const std::string&>().size() << " bytes, more than "
                         << limits.max_json_string << " "
                         << LimitHint(limits.max_json_string, "TROCAR_MAX_JSON_STRING"));
    }
  };
  // Runs on every event as the parser meets it, before the value is built into the document.
  json::parser_callback_t check = [&](int /*depth*/, json::parse_event_t event, json& parsed) {
    switch (event) {
      case json::parse_event_t::object_start:
      case json::parse_event_t::array_start: {
        const std::string at = ChildPath(open);
        counted(at);
        if (static_cast<int>(open.size()) >= limits.max_json_depth) {
          const std::string shown = at.size() > 80 ? at.substr(0, 80) + "..." : at;
          TROCAR_THROW(where << ": " << (shown.empty() ? "the document" : shown)
                             << ": nested deeper than " << limits.max_json_depth << " levels "
                             << LimitHint(static_cast<std::uint64_t>(limits.max_json_depth),
                                          "TROCAR_MAX_JSON_DEPTH"));
        }
        Open o;
        o.array = event == json::parse_event_t::array_start;
        o.path = at;
        open.push_back(std::move(o));
        break;
      }
      case json::parse_event_t::key: {
        bounded_string(parsed, ChildPath(open) + " (a key)");
        Open& top = open.back();
        top.key = parsed.get<std::string>();
        if (!top.keys.insert(top.key).second) {
          TROCAR_THROW(where << ": " << ChildPath(open)
                             << ": the key is given twice in one object (which one is meant?)");
        }
        break;
      }
      case json::parse_event_t::object_end:
      case json::parse_event_t::array_end:
        open.pop_back();
        if (!open.empty() && open.back().array) ++open.back().next;
        break;
      case json::parse_event_t::value:
        counted(ChildPath(open));
        bounded_string(parsed, ChildPath(open));
        if (!open.empty() && open.back().array) ++open.back().next;
        break;
    }
    return true;
  };
  try {
    return json::parse(text, check);
  } catch (const json::exception& e) {
    TROCAR_THROW(where << ": not " << kind << " (JSON: " << e.what() << ")");
  }
}

json ReadJsonFile(const std::string& path, const std::string& kind) {
  return ParseJsonText(ReadTextFile(path), path, kind);
}

int JsonInt(const json& value, const std::string& where, const std::string& field,
            std::int64_t lo, std::int64_t hi) {
  bool ok = false;
  std::int64_t v = 0;
  if (value.is_number_unsigned()) {
    const std::uint64_t u = value.get<std::uint64_t>();
    ok = u <= static_cast<std::uint64_t>(INT64_MAX);
    v = static_cast<std::int64_t>(u);
  } else if (value.is_number_integer()) {
    ok = true;
    v = value.get<std::int64_t>();
  }
  lo = std::max<std::int64_t>(lo, INT32_MIN);
  hi = std::min<std::int64_t>(hi, INT32_MAX);
  TROCAR_THROW_UNLESS(ok && v >= lo && v <= hi,
                      where << ": " << field << ": expected an integer in [" << lo << ", " << hi
                            << "], found " << value.dump().substr(0, 40));
  return static_cast<int>(v);
}

}  // namespace trocar
