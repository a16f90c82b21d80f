#pragma once
// A run's output files as one transaction: a design writes nine files (metrics.json,
// surface.stl, ...), and a run that is killed, or a disk that fills, between the first
// and the last must not leave a folder that reads as a complete result.
//
// Files are written into a hidden staging folder inside the output folder
// (".freeform-staging-<pid>-<n>", same file system, so moves are renames). commit()
// then moves the previous run's files of the same names aside (the marker, metrics.json,
// first), moves the new ones into place (the marker last) and deletes the old ones.
// The rule a reader can rely on: when metrics.json is there, every file written with it
// is complete and from the same run. A failed commit puts the previous files back. A
// staging folder left by a killed process is removed by the next run in that folder.
#include <cerrno>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#if defined(__unix__) || defined(__APPLE__)
#include <signal.h>
#include <unistd.h>
#endif

#include "../core/error.hpp"

namespace freeform::io {

class StagedOutput {
public:
    static constexpr const char* staging_prefix = ".freeform-staging-";

    // Creates `out` when it is missing and a fresh staging folder in it; removes the
    // staging folders of processes that no longer run. Throws IoError naming the folder.
    explicit StagedOutput(std::filesystem::path out) : out_(std::move(out)) {
        namespace fs = std::filesystem;
        std::error_code ec;
        fs::create_directories(out_, ec);
        if (ec) throw IoError("cannot create the output folder '" + out_.string() + "': " + ec.message());
        remove_abandoned_staging();
        std::random_device entropy;
        for (int attempt = 0; attempt < 16 && staging_.empty(); ++attempt) {
            const fs::path candidate = out_ / (staging_prefix + std::to_string(process_id()) + "-" +
                                               std::to_string(entropy()));
            if (fs::create_directory(candidate, ec) && !ec) staging_ = candidate;
        }
        if (staging_.empty())
            throw IoError("cannot write into the output folder '" + out_.string() + "'" +
                          (ec ? ": " + ec.message() : std::string()));
    }

    StagedOutput(const StagedOutput&) = delete;
    StagedOutput& operator=(const StagedOutput&) = delete;

    // Without a commit nothing of this run stays: the staging folder goes.
    ~StagedOutput() {
        std::error_code ignored;
        if (!staging_.empty()) std::filesystem::remove_all(staging_, ignored);
    }

    const std::filesystem::path& folder() const { return out_; }

    // Calls write(path) to write the output file `name` (a plain file name) into the
    // staging folder. An IoError it throws is thrown again naming out/name, the file the
    // user asked for, instead of the staged one.
    template <class Write>
    void write(const std::string& name, Write&& write) {
        if (name.empty() || name.find('/') != std::string::npos || name == "." || name == "..")
            throw InputError("StagedOutput::write: '" + name + "' is not a plain file name");
        try {
            write(staging_ / name);
        } catch (const IoError& e) {
            throw IoError(replace_all(e.what(), (staging_ / name).string(), (out_ / name).string()));
        }
        names_.push_back(name);
    }

    // Moves every written file into the output folder, `marker` (written last, when it
    // was written) after all the others; see the file comment. Throws IoError naming the
    // file that could not be moved, after putting the previous files back.
    void commit(const std::string& marker = "metrics.json") {
        namespace fs = std::filesystem;
        std::vector<std::string> order;
        bool has_marker = false;
        for (const std::string& n : names_)
            if (n == marker)
                has_marker = true;
            else
                order.push_back(n);
        if (has_marker) order.push_back(marker);

        // A folder where an output file goes is the user's, not a previous result: refuse
        // before anything moves.
        std::error_code ec;
        for (const std::string& n : order)
            if (fs::is_directory(fs::symlink_status(out_ / n, ec)))
                throw IoError("cannot write '" + (out_ / n).string() + "': a folder of that name is in the way");
        const fs::path previous = staging_ / ".previous";
        fs::create_directory(previous, ec);
        if (ec) throw IoError("cannot write into '" + staging_.string() + "': " + ec.message());
        struct Step {
            std::string name;
            bool old_moved = false, new_moved = false;
        };
        std::vector<Step> steps;  // in the order the new files move in: the marker last
        for (const std::string& n : order) steps.push_back({n});
        try {
            // The previous marker goes first: from then on the folder does not read as complete.
            for (std::size_t k = 0; k < steps.size(); ++k) {
                Step& s = steps[has_marker ? (k + steps.size() - 1) % steps.size() : k];
                if (!fs::exists(fs::symlink_status(out_ / s.name, ec))) continue;
                move(out_ / s.name, previous / s.name);
                s.old_moved = true;
            }
            for (Step& s : steps) {
                move(staging_ / s.name, out_ / s.name);
                s.new_moved = true;
            }
        } catch (const IoError&) {
            for (auto s = steps.rbegin(); s != steps.rend(); ++s) {
                std::error_code ignored;
                if (s->new_moved) fs::rename(out_ / s->name, staging_ / s->name, ignored);
                if (s->old_moved) fs::rename(previous / s->name, out_ / s->name, ignored);
            }
            throw;
        }
        fs::remove_all(staging_, ec);  // the previous files; a failure here loses nothing
        staging_.clear();
    }

private:
    static long process_id() {
#if defined(__unix__) || defined(__APPLE__)
        return long(::getpid());
#else
        return 0;
#endif
    }

    static bool process_running(long pid) {
#if defined(__unix__) || defined(__APPLE__)
        return pid > 0 && (::kill(pid_t(pid), 0) == 0 || errno == EPERM);
#else
        (void)pid;
        return true;  // no way to tell: keep the folder
#endif
    }

    void remove_abandoned_staging() const {
        namespace fs = std::filesystem;
        std::error_code ec;
        const std::string prefix = staging_prefix;
        for (fs::directory_iterator it(out_, ec), end; !ec && it != end; it.increment(ec)) {
            const std::string name = it->path().filename().string();
            if (name.compare(0, prefix.size(), prefix) != 0) continue;
            const long pid = std::strtol(name.c_str() + prefix.size(), nullptr, 10);
            std::error_code ignored;
            if (!process_running(pid)) fs::remove_all(it->path(), ignored);
        }
    }

    static void move(const std::filesystem::path& from, const std::filesystem::path& to) {
        std::error_code ec;
        std::filesystem::rename(from, to, ec);
        if (ec) throw IoError("cannot move '" + from.string() + "' to '" + to.string() + "': " + ec.message());
    }

    static std::string replace_all(std::string text, const std::string& from, const std::string& to) {
        if (from.empty()) return text;
        for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
            text.replace(at, from.size(), to);
        return text;
    }

    std::filesystem::path out_;
    std::filesystem::path staging_;
    std::vector<std::string> names_;
};

}  // namespace freeform::io
