# meshwiki server image. Build: docker compose build. Data lives in the /data volume.
FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release -p meshwiki \
 && install -m 0755 target/release/meshwiki /usr/local/bin/meshwiki

FROM debian:bookworm-slim
RUN apt-get update \
 && apt-get install -y --no-install-recommends ca-certificates \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --home-dir /data --shell /usr/sbin/nologin meshwiki \
 && mkdir -p /data && chown meshwiki:meshwiki /data
COPY --from=build /usr/local/bin/meshwiki /usr/local/bin/meshwiki
USER meshwiki
ENV MESHWIKI_DATA_DIR=/data \
    MESHWIKI_BIND=0.0.0.0:8080
VOLUME ["/data"]
EXPOSE 8080
ENTRYPOINT ["meshwiki"]
CMD ["serve"]
