# meshwiki server image. Build: docker compose build. Data lives in the /data volume.
FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release -p meshwiki \
 && install -m 0755 target/release/meshwiki /usr/local/bin/meshwiki

# The 3D viewer's front-end packages, as pinned by static/package-lock.json.
FROM node:20-bookworm-slim AS web
WORKDIR /web
COPY static/package.json static/package-lock.json ./
RUN npm ci --omit=dev --no-audit --no-fund

# The runtime: the binary, the viewer's packages and a Vulkan driver. Mesa's software driver
# (lavapipe, in mesa-vulkan-drivers) lets the server render (thumbnails, the render API, region
# selection) with no GPU; with one passed through (see README, "Container"), `auto` picks it.
# scripts/check-image installs exactly the packages of the next line in a clean root and runs
# the binary's render self-test there, so this list is checked without Docker.
FROM debian:bookworm-slim
RUN apt-get update \
 && apt-get install -y --no-install-recommends ca-certificates libvulkan1 mesa-vulkan-drivers \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --home-dir /data --shell /usr/sbin/nologin meshwiki \
 && mkdir -p /data && chown meshwiki:meshwiki /data
COPY --from=build /usr/local/bin/meshwiki /usr/local/bin/meshwiki
COPY --from=web /web/node_modules /usr/share/meshwiki/node_modules
# Fails the image build when the renderer cannot draw with these packages.
RUN meshwiki render-check --adapter software
USER meshwiki
ENV MESHWIKI_DATA_DIR=/data \
    MESHWIKI_BIND=0.0.0.0:8080 \
    MESHWIKI_NODE_MODULES=/usr/share/meshwiki/node_modules
VOLUME ["/data"]
EXPOSE 8080
ENTRYPOINT ["meshwiki"]
CMD ["serve"]
