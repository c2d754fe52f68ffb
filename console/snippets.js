// The request the console just sent, as a user would send it: a curl command against the
// HTTP API and a call of the Python client (gRPC). Images and masks are read from files
// named after the ones chosen, not pasted.

const json = (v) => JSON.stringify(v);

// `request`: the JSON body sent; `files`: {photo, mask} file names; `keyed`: whether the
// server needs a key.
export function curl(request, files, keyed) {
  const body = structuredClone(request);
  body.image = { encoded: "$PHOTO" };
  const lines = [`PHOTO=$(base64 -w0 ${quote(files.photo)})`];
  for (const d of body.detections ?? []) {
    if (d.mask_png) {
      d.mask_png = "$MASK";
      lines.push(`MASK=$(base64 -w0 ${quote(files.mask)})   # white: the object`);
    }
  }
  if (body.depth) {
    body.depth.png16 = "$DEPTH";
    lines.push(`DEPTH=$(base64 -w0 ${quote(files.depth ?? "depth.png")})   # 16-bit, ${body.depth.scale_mm} mm per unit`);
  }
  lines.push(`curl -sS ${location.origin}/v1/estimate \\`, `  -H 'Content-Type: application/json' \\`);
  if (keyed) lines.push(`  -H "Authorization: Bearer $B2TF_API_KEY" \\`);
  // An unquoted heredoc: the shell puts the files' base64 in, with no argument-length limit.
  lines.push(`  --data-binary @- <<EOF`, json(body), "EOF");
  return lines.join("\n");
}

export function python(request, files, keyed) {
  const k = request.intrinsics;
  const o = request.options;
  const args = [`${quote(files.photo, '"')}`, `K`];
  if (request.objects?.length) args.push(`objects=${json(request.objects)}`);
  else args.push(`[${request.detections.map((d) => detection(d, files)).join(", ")}]`);
  args.push(`rrc=${o.rrc ? "True" : "False"}`, `verify=${o.verify ? "True" : "False"}`);
  // The client's keyword arguments carry the API options' names.
  for (const name of ["rrc_always", "refiner", "verify_templates", "verify_matched", "spin_steps", "nudge_degrees", "depth_views", "box_prior"]) {
    if (o[name] !== undefined) args.push(`${name}=${pythonValue(o[name])}`);
  }
  if (request.depth) args.push(`depth=${quote(files.depth ?? "depth.png", '"')}`, `depth_scale=${json(request.depth.scale_mm)}`);
  return [
    "import os",
    "import b2tfpose",
    "",
    "# The server's gRPC address (b2tf serve --grpc; 127.0.0.1:50051 by default).",
    `client = b2tfpose.Client("${location.hostname}:50051"${keyed ? ', api_key=os.environ["B2TF_API_KEY"]' : ""})`,
    `K = (${k.fx}, ${k.fy}, ${k.cx}, ${k.cy})  # fx, fy, cx, cy in pixels`,
    `for r in client.estimate(${args.join(", ")}):`,
    "    print(r.object_id, r.score, r.pose.R if r.pose else r.reason, r.pose.t if r.pose else '')",
  ].join("\n");
}

// JSON's form is Python's too, but for true and false.
function pythonValue(v) {
  return typeof v === "boolean" ? (v ? "True" : "False") : json(v);
}

function detection(d, files) {
  const where = d.mask_png ? `mask=${quote(files.mask, '"')}` : `box=(${d.bbox.join(", ")})`;
  return `b2tfpose.Detection(object_id=${json(d.object_id)}, ${where})`;
}

// A file name for a shell (single quotes) or Python (double quotes).
function quote(name, q = "'") {
  return q === "'" ? `'${name.replaceAll("'", "'\\''")}'` : json(name);
}
