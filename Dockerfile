# railmon: multi-stage build of `railmon` (service + offline analysis) and `sensors-replay`.
#
#   docker build -t railmon .
#   docker run --rm --ipc=host -v railmon-iox:/tmp/iceoryx2 -p 8787:8787 \
#       -e RAILMON_HTTP__LISTEN=0.0.0.0:8787 railmon
#   docker run --rm --ipc=host -v railmon-iox:/tmp/iceoryx2 railmon \
#       sensors-replay drive --scenario config/scenarios/adhesion-seed.toml --loop
#
# The two processes talk over iceoryx2 shared memory: both containers need the same /dev/shm
# (--ipc=host or --ipc=container:<name>), the same iceoryx2 root path (the volume on
# /tmp/iceoryx2) and the same uid (files are created 0600). See docs/service.md.

FROM rust:1-bookworm AS build
WORKDIR /src
COPY . .
# Only the two binaries (and what they depend on); no network access is needed beyond crates.io.
RUN cargo build --release --locked -p railmon-service -p sensors-replay \
 && cp target/release/railmon target/release/sensors-replay /usr/local/bin/

FROM debian:bookworm-slim
RUN useradd --system --uid 10001 --home-dir /opt/railmon railmon
WORKDIR /opt/railmon
COPY --from=build /usr/local/bin/railmon /usr/local/bin/sensors-replay /usr/local/bin/
COPY config ./config
USER railmon
EXPOSE 8787
ENV RAILMON_CONFIG=/opt/railmon/config/railmon.toml
ENTRYPOINT []
CMD ["railmon", "serve"]
