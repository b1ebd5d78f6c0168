# railmon: two images from one file, both on the same Debian bookworm base.
#   target `railmon` (the last stage, the default): the onboard `railmon` (all but `analyze`:
#     built with `--no-default-features`, no plotting or font code, so no libfontconfig) and
#     `sensors-replay`, packaging binaries built by cargo on the host;
#   target `monitoring`: the ground's Prometheus, Alertmanager and NATS server (JetStream),
#     Debian's packages (the ones the system tests run), for compose.yaml.
#
# Why host-built binaries and no `rust` build stage: the machines this project is built and
# soak-tested on reach crates.io and Debian's mirror but no image registry and no rustup from
# inside a container (Debian's own rustc is older than the workspace's rust-version); the host's
# cargo build (Cargo.lock, the same bookworm glibc, the warm target dir that cargo reuses like
# cargo-chef's cached layers) is the one the tests ran. `scripts/docker-image` does it all (cargo
# build, engine, base image, docker build of both targets); by hand, on a machine that can pull
# `debian:bookworm-slim`:
#
#   cargo build --release --locked -p railmon-service --no-default-features --bin railmon
#   cargo build --release --locked -p sensors-replay
#   docker build -t railmon:dev .                               # context: .dockerignore
#   docker build --target monitoring -t railmon-monitoring:dev .
#   docker-compose up -d                                        # compose.yaml
#
# The processes talk over iceoryx2 shared memory: every container of one vehicle needs the same
# /dev/shm (compose: `ipc: shareable` / `ipc: service:<service>`), the same iceoryx2 root path
# (a volume on /run/railmon, the private default root path) and the same uid (the bus files are
# private to it): this image's user 10001.

# A registry-less machine passes a locally imported Debian bookworm (scripts/docker-image).
ARG BASE_IMAGE=debian:bookworm-slim

FROM ${BASE_IMAGE} AS monitoring
LABEL org.opencontainers.image.title=railmon-monitoring
# policy-rc.d: the packages' maintainer scripts must not try to start services in a build.
# Debian's packages create the users `prometheus` (both daemons run as it) and `nats`, and the
# Prometheus state dirs; /var/lib/nats (JetStream's store, dashboards/nats/nats.conf) belongs to
# `nats`, so that a fresh named volume mounted there inherits it.
COPY scripts/http-probe /usr/local/bin/http-probe
RUN printf '#!/bin/sh\nexit 101\n' >/usr/sbin/policy-rc.d \
 && chmod 0755 /usr/sbin/policy-rc.d \
 && apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        prometheus prometheus-alertmanager nats-server \
 && install -d -o nats -g nats -m 0700 /var/lib/nats \
 && apt-get clean \
 && rm -rf /var/lib/apt/lists/* /var/cache/apt/*.bin /usr/sbin/policy-rc.d
USER prometheus
WORKDIR /var/lib/prometheus
CMD ["prometheus", "--version"]

FROM ${BASE_IMAGE} AS railmon
LABEL org.opencontainers.image.title=railmon
# Where the two binaries are, relative to the build context.
ARG BIN_DIR=target/release

# The bus root path /run/railmon (railmon's private default, docs/reliability.md) and the event
# store /var/lib/railmon exist and belong to the user, 0700, so that a fresh named volume
# mounted on either inherits owner and mode (Docker copies the image's directory into an empty
# volume).
RUN groupadd --gid 10001 railmon \
 && useradd --uid 10001 --gid 10001 --no-create-home --home-dir /opt/railmon railmon \
 && install -d -o railmon -g railmon -m 0700 /run/railmon /var/lib/railmon
WORKDIR /opt/railmon
COPY scripts/http-probe /usr/local/bin/http-probe
COPY ${BIN_DIR}/railmon ${BIN_DIR}/sensors-replay /usr/local/bin/
COPY config ./config
COPY data ./data
USER railmon
EXPOSE 8787
# Read by `railmon serve` and `sensors-replay` (clap `env = "RAILMON_CONFIG"`), like --config.
ENV RAILMON_CONFIG=/opt/railmon/config/railmon.toml
ENV RAILMON_STORAGE__DATA_DIR=/var/lib/railmon
# The damper filters' gain grids, solved here once instead of at every service start: every
# speed at the design mass and at the masses a filter without a load signal carries (550 nodes,
# about 3 min of a core and 533 MB; docs/service.md): /var/lib/railmon/gain-cache, copied with
# the directory into a fresh volume.
RUN ["railmon", "damper", "warm-cache"]
ENTRYPOINT []
CMD ["railmon", "serve"]
