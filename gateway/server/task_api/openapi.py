"""``docs/tasks.md``: the task API's reference, rendered from the OpenAPI document FastAPI
generates (:func:`gateway.server.http_app.openapi_document`, served at ``GET /openapi.json``):
nothing in it is written by hand but the routes' words in their declarations."""

from __future__ import annotations

from typing import Any

from gateway.server.http_app import openapi_document


def _type(schema: dict[str, Any]) -> str:
    """A short name of a JSON schema's type."""
    if "$ref" in schema:
        return str(schema["$ref"]).rsplit("/", 1)[-1]
    if "anyOf" in schema:
        return " or ".join(_type(s) for s in schema["anyOf"])
    if "oneOf" in schema:
        return " or ".join(_type(s) for s in schema["oneOf"])
    kind = schema.get("type", "any")
    if kind == "array":
        items = schema.get("items") or schema.get("prefixItems")
        if isinstance(items, list):
            return "[" + ", ".join(_type(s) for s in items) + "]"
        return f"list of {_type(items or {})}"
    if "enum" in schema:
        return " \\| ".join(f"`{v}`" for v in schema["enum"])
    if "const" in schema:
        return f"`{schema['const']}`"
    return str(kind)


def markdown() -> str:
    """``docs/tasks.md``: the task API, rendered from :func:`openapi_document` (a test keeps
    the file in step: ``python -m gateway.server.task_api.openapi > docs/tasks.md``)."""
    doc = openapi_document()
    out = ["# The task API", "",
           "Generated from the gateway's OpenAPI document (`GET /openapi.json`) by "
           "`python -m gateway.server.task_api.openapi`; do not edit.", "",
           doc["info"]["description"], "",
           "Credentials: `Authorization: Bearer <operator token>`, or the GUI's login "
           "cookie (changes also need the gateway's own `Origin`). Every refusal is a 4xx "
           "(or 503) with `{\"error\": \"<one line>\"}`. Changes are journaled and committed "
           "before they are answered.", "", "## Routes", ""]
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            out += [f"### `{method.upper()} {path}`", "", op["summary"] + ".", ""]
            if "description" in op:
                out += [op["description"], ""]
            for p in op.get("parameters", []):
                out.append(f"- {p['in']} `{p['name']}`: {_type(p['schema'])}"
                           + (f" ({p['description']})" if "description" in p else ""))
            out += [f"- {code}: {r['description']}" + "".join(
                f" (`{_type(c['schema'])}`)" for c in r.get("content", {}).values()
                if "$ref" in c.get("schema", {})) for code, r in op["responses"].items()]
            out.append("")
    out += ["## Models", ""]
    for name, schema in doc["components"]["schemas"].items():
        out += [f"### {name}", "", " ".join(schema.get("description", "").split()), "",
                "| field | type | required |", "| --- | --- | --- |"]
        required = set(schema.get("required", []))
        for field, prop in schema.get("properties", {}).items():
            out.append(f"| `{field}` | {_type(prop)} | {'yes' if field in required else ''} |")
        out.append("")
    return "\n".join(out)


if __name__ == "__main__":
    print(markdown(), end="")
