#!/bin/sh
# Runs each libFuzzer harness of a PEN_FUZZ build for a set time (`make fuzz`; fuzz/README.md).
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
    [ -x "$exe" ] || { echo "fuzz: $exe missing (build with PEN_FUZZ=ON)"; failed="$failed $path"; continue; }
    dicts=""
    [ -f "$src/fuzz/dict/$path.dict" ] && dicts="-dict=$src/fuzz/dict/$path.dict"
    mkdir -p "$build/fuzz-corpus/$path" "$build/fuzz-findings/$path"
    log="$build/fuzz-logs/$path.log"
    echo "fuzz: $path for ${seconds} s (log $log)"
    # -jobs=1: one process, the machine may be shared; -timeout: a hang is an input over 10 s.
    "$exe" "$build/fuzz-corpus/$path" "$src/fuzz/corpus/$path" "$src/fuzz/regressions/$path" \
        $dicts -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
        -artifact_prefix="$build/fuzz-findings/$path/" >"$log" 2>&1
    rc=$?
    grep -E '^#[0-9]+ +(DONE|INITED)|stat::number_of_executed_units|stat::peak_rss_mb' "$log" | sed 's/^/    /'
    if [ $rc -ne 0 ]; then
        echo "fuzz: $path FAILED (exit $rc): see $log and $build/fuzz-findings/$path/"
        failed="$failed $path"
    fi
done
[ -z "$failed" ] || { echo "fuzz: findings in:$failed"; exit 1; }
echo "fuzz: no findings"
