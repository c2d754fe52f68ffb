"""Validates the served OpenAPI document (src/service/openapi.json) against the OpenAPI 3
specification with openapi-spec-validator; exits non-zero naming the problem."""

import json
import sys

from openapi_spec_validator import validate

path = sys.argv[1] if len(sys.argv) > 1 else "src/service/openapi.json"
with open(path, encoding="utf-8") as f:
    validate(json.load(f))
print(f"{path}: valid OpenAPI")
