# railmon: runtime image of `railmon` (service + offline analysis) and `sensors-replay`, packaging
# binaries built by cargo on the host.
#
# Why host-built binaries and no `rust` build stage: the machines this project is built and
# soak-tested on reach crates.io and Debian's mirror but no image registry and no
# rustup from inside a container; the host's cargo build (Cargo.lock, the same bookworm glibc)
# is the one the tests ran. `scripts/docker-image` does it all (cargo build, engine, base image,
# docker build); by hand, on a machine that can pull `debian:bookworm-slim`:
#
#   cargo build --release --locked -p railmon-service -p sensors-replay
#   docker build -t railmon .                     # context: config/ + the two binaries (.dockerignore)
#   docker run --rm --name railmon --ipc=shareable -v railmon-iox:/tmp/iceoryx2 \
#       -p 127.0.0.1:8787:8787 -e RAILMON_HTTP__LISTEN=0.0.0.0:8787 railmon
#   docker run --rm --ipc=container:railmon -v railmon-iox:/tmp/iceoryx2 railmon \
#       sensors-replay drive --scenario config/scenarios/adhesion-seed.toml --loop
#
# The processes talk over iceoryx2 shared memory: every container needs the same /dev/shm
# (--ipc=container:<service>, or --ipc=host), the same iceoryx2 root path (the volume on
# /tmp/iceoryx2) and the same uid (files are created 0600): this image's user 10001.
# `sensors-replay vehicle --scenario config/scenarios/fuel-cycles.toml` reads the drive cycles
# at data/drive-cycles (copied into the image with their licence).

# A registry-less machine passes a locally imported Debian bookworm (scripts/docker-image).
ARG BASE_IMAGE=debian:bookworm-slim
FROM ${BASE_IMAGE}
LABEL org.opencontainers.image.title=railmon
# Where the two binaries are, relative to the build context.
ARG BIN_DIR=target/release

# `railmon` links libfontconfig (plotters' text for `railmon analyze` plots; it pulls freetype,
# png and the DejaVu fonts). The iceoryx2 root path exists and belongs to the user, so that a
# fresh named volume mounted on it inherits the owner (Docker copies the image's directory into
# an empty volume).
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends libfontconfig1 \
 && apt-get clean \
 && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin \
 && groupadd --gid 10001 railmon \
 && useradd --uid 10001 --gid 10001 --no-create-home --home-dir /opt/railmon railmon \
 && mkdir -p /tmp/iceoryx2 \
 && chown railmon:railmon /tmp/iceoryx2 \
 && chmod 0700 /tmp/iceoryx2
WORKDIR /opt/railmon
COPY ${BIN_DIR}/railmon ${BIN_DIR}/sensors-replay /usr/local/bin/
COPY config ./config
COPY data ./data
USER railmon
EXPOSE 8787
# Read by `railmon serve` and `sensors-replay` (clap `env = "RAILMON_CONFIG"`), like --config.
ENV RAILMON_CONFIG=/opt/railmon/config/railmon.toml
# The bus root path: the shared volume, private to uid 10001 (docs/reliability.md).
ENV RAILMON_BUS__ROOT_PATH=/tmp/iceoryx2/
ENTRYPOINT []
CMD ["railmon", "serve"]
