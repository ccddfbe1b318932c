# phenomena: the HTTP rendering service.
#   docker build -t phenomena .
#   docker run --rm -p 8080:8080 -v phenomena-data:/data phenomena
# or `docker compose up` (docker-compose.yml). The build context is the repository root; what it
# leaves out is in .dockerignore (target/, data directories, .git).

# ---- build -------------------------------------------------------------------------------------
FROM rust:1-slim-bookworm AS build
WORKDIR /src
# The whole workspace: Cargo.toml/Cargo.lock, src/, engine/ (the compute crate), benches/ (named
# in Cargo.toml, so cargo needs them even for `build`), tests/, openapi.yaml (include_str!-ed by
# src/api/system.rs), build.rs and web/ (the page, and the npm manifests of its third-party
# code). A stub-manifest layer for dependency caching was left out on purpose: it must mirror
# every [[bench]] target in the manifests and breaks when one is added; a full release build
# takes about 4 minutes on 2 cores.
# Node.js with npm: build.rs installs the studio page's third-party code (three.js, for the 3-D
# viewer) from the npm registry with `npm ci` (web/package.json + web/package-lock.json) and embeds
# it in the binary; the runtime image needs no Node. Without npm the build still succeeds and the
# page says that its 3-D viewer is not installed.
# g++: the `meshopt` crate compiles meshoptimizer's C++ (snow_cover/simplify.rs); the slim image
# has only the C compiler.
RUN apt-get update \
    && apt-get install -y --no-install-recommends nodejs npm g++ \
    && rm -rf /var/lib/apt/lists/*
COPY . .
RUN cargo build --release --locked --bin phenomena \
    && install -D -m 0755 target/release/phenomena /out/phenomena

# ---- run ---------------------------------------------------------------------------------------
FROM debian:bookworm-slim
# curl for the HEALTHCHECK; ca-certificates for any future outbound TLS.
RUN apt-get update \
    && apt-get install -y --no-install-recommends curl ca-certificates \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --system --gid 10001 phenomena \
    && useradd --system --uid 10001 --gid phenomena --home-dir /data --no-create-home \
       --shell /usr/sbin/nologin phenomena \
    && mkdir -p /data \
    && chown phenomena:phenomena /data
COPY --from=build /out/phenomena /usr/local/bin/phenomena

# Listen on every interface inside the container (the default 127.0.0.1 is unreachable from
# outside it); jobs, assets and outputs live on the /data volume.
ENV PHENOMENA_BIND=0.0.0.0:8080 \
    PHENOMENA_DATA_DIR=/data
VOLUME /data
EXPOSE 8080
USER phenomena:phenomena
WORKDIR /data

HEALTHCHECK --interval=30s --timeout=3s --start-period=10s --retries=3 \
    CMD curl -fsS http://127.0.0.1:8080/healthz || exit 1

# SIGTERM (docker stop) drains: no new jobs, running jobs get PHENOMENA_SHUTDOWN_GRACE_SECS
# (default 30) to finish, the rest stay queued in /data for the next start. Give `docker stop`
# a longer timeout than the grace period (docker-compose.yml sets stop_grace_period: 40s).
STOPSIGNAL SIGTERM
ENTRYPOINT ["/usr/local/bin/phenomena"]
CMD ["serve"]
