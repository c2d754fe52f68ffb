#!/bin/bash
# The image's HEALTHCHECK: GET /readyz on the HTTP listener with bash's /dev/tcp, so the
# image needs no curl. Healthy = "200" (warmed up); the port comes from B2TF_HTTP_ADDR.
# Plain HTTP only: with TLS on, probe from outside (docs/deploy.md).
port="${B2TF_HTTP_ADDR##*:}"
exec 3<>"/dev/tcp/127.0.0.1/${port:-8080}" || exit 1
printf 'GET /readyz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n' >&3
read -r -t 5 _ status _ <&3 && [ "$status" = 200 ]
