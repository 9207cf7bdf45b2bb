#!/bin/sh
# Runs each libFuzzer harness of a PEN_FUZZ build for a set time (`make fuzz`,
# docs/reliability.md).
#     sh scripts/fuzz.sh BUILD_DIR SECONDS PATH...
# Each fuzzer starts from the committed seeds (fuzz/corpus/<path>, fuzz/regressions/<path>) and
# writes the inputs it finds interesting into BUILD_DIR/fuzz-corpus/<path>, so the repository's
# corpus changes only by hand. Findings (crash, leak, hang over 10 s, more than 2 GB) go to
# BUILD_DIR/fuzz-findings/<path>/; the run goes on with the next harness and fails at the end.
# The last lines of each run (libFuzzer's executions, cov and ft) go to BUILD_DIR/fuzz-logs.
set -u
build=$1; seconds=$2; shift 2
src=$(cd "$(dirname "$0")/.." && pwd)
mkdir -p "$build/fuzz-logs"
failed=""
for path in "$@"; do
    exe="$build/fuzz/fuzz_$path"
    if [ ! -x "$exe" ]; then
        echo "fuzz: $exe missing (build with PEN_FUZZ=ON)"
        failed="$failed $path"
        continue
    fi
    dicts=""
    [ -f "$src/fuzz/dict/$path.dict" ] && dicts="-dict=$src/fuzz/dict/$path.dict"
    mkdir -p "$build/fuzz-corpus/$path" "$build/fuzz-findings/$path"
    log="$build/fuzz-logs/$path.log"
    echo "fuzz: $path for ${seconds} s (log $log)"
    # -fork=1: one child process at a time (the machine may be shared) that is restarted after
    # a finding, so one run collects every finding instead of stopping at the first;
    # -timeout: a hang is an input over 10 s.
    before=$(ls "$build/fuzz-findings/$path" | wc -l)
    seeds="$src/fuzz/corpus/$path"
    [ -d "$src/fuzz/regressions/$path" ] && seeds="$seeds $src/fuzz/regressions/$path"
    "$exe" "$build/fuzz-corpus/$path" $seeds \
        $dicts -fork=1 -ignore_crashes=1 -ignore_timeouts=1 -ignore_ooms=1 \
        -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 \
        -artifact_prefix="$build/fuzz-findings/$path/" >"$log" 2>&1
    rc=$?
    tail -n 1 "$log" | sed 's/^/    /'
    after=$(ls "$build/fuzz-findings/$path" | wc -l)
    if [ $rc -ne 0 ] || [ "$after" -gt "$before" ]; then
        echo "fuzz: $path: $((after - before)) new finding(s) (exit $rc): $build/fuzz-findings/$path/"
        failed="$failed $path"
    fi
done
[ -z "$failed" ] || { echo "fuzz: findings in:$failed"; exit 1; }
echo "fuzz: no findings"
