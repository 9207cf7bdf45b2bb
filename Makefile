# penumbra: the two commands of the README, and a few more for developers.
#   make demo   install missing Debian packages, build, run the main job on the bundled data
#   make test   install missing Debian packages, build, run the whole test suite (ctest)
# Developers: make build | make test-asan | make fuzz | make bench | make generate | make clean
#   make install [PREFIX=/usr/local] [DESTDIR=...]   cmake --install of the build (README "Install")
JOBS   ?= $(shell nproc)
BUILD  ?= build
PREFIX ?= /usr/local

.PHONY: all deps build demo test test-asan fuzz bench generate install clean

all: build

deps:
	@sh scripts/install-deps.sh

build: deps
	@cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=Release >/dev/null
	@cmake --build $(BUILD) -j $(JOBS)

demo: build
	@sh scripts/demo.sh $(BUILD)/penumbra

test: build
	@cd $(BUILD) && ctest --output-on-failure -j $(JOBS)

# Same suite under AddressSanitizer + UndefinedBehaviorSanitizer, smaller sizes (PEN_TEST_QUICK).
test-asan: deps
	@cmake -S . -B $(BUILD)-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPEN_SANITIZE=ON >/dev/null
	@cmake --build $(BUILD)-asan -j $(JOBS)
	@cd $(BUILD)-asan && ASAN_OPTIONS=detect_leaks=1 PEN_TEST_QUICK=1 ctest --output-on-failure -j $(JOBS)

# libFuzzer harnesses (docs/reliability.md), built with clang + ASan + UBSan in their own tree,
# each run for FUZZ_SECONDS; FUZZ_PATHS picks the harnesses. The replays of the stored inputs
# are part of `make test` (ctest -R fuzz_).
FUZZ_SECONDS ?= 60
FUZZ_PATHS   ?= obj ply png jpeg hdr exr scene spheres task checkpoint cameras
fuzz:
	@sh scripts/install-deps.sh --fuzz
	@cmake -S . -B $(BUILD)-fuzz -DCMAKE_C_COMPILER=clang-14 -DCMAKE_CXX_COMPILER=clang++-14 \
	    -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPEN_FUZZ=ON -DPEN_TESTS=OFF >/dev/null
	@cmake --build $(BUILD)-fuzz -j $(JOBS) --target fuzzers
	@sh scripts/fuzz.sh $(BUILD)-fuzz $(FUZZ_SECONDS) $(FUZZ_PATHS)

bench: build
	@$(BUILD)/penumbra bench

# Regenerates the generated SH code from its generators (tests/cli_generated.sh checks that the
# committed files match). Each file is written beside itself first, so a failing generator leaves
# the committed one as it was.
PYTHON ?= /usr/bin/python3
# Each entry: OUTPUT:GENERATOR[:ARGUMENT].
GENERATED = src/sh/tables.c:scripts/gen_sh_tables.py \
            $(foreach L,3 4 5 6,src/sh/sh_fast_product_$(L).inc:scripts/gen_sh_fast.py:$(L))
generate:
	@set -e; for pair in $(GENERATED); do \
	    out=$${pair%%:*}; rest=$${pair#*:}; gen=$${rest%%:*}; arg=; \
	    [ "$$rest" = "$$gen" ] || arg=$${rest#*:}; \
	    PYTHONDONTWRITEBYTECODE=1 $(PYTHON) $$gen $$arg > $$out.tmp && mv $$out.tmp $$out || { rm -f $$out.tmp; exit 1; }; \
	    echo "generated $$out ($$gen)"; \
	done

install: build
	@cmake --install $(BUILD) --prefix $(PREFIX)

clean:
	rm -rf $(BUILD) $(BUILD)-asan $(BUILD)-fuzz
