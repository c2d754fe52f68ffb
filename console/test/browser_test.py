"""The web console end to end in a real browser: headless Chromium (Debian's, driven by its
chromedriver through Selenium) against a real `b2tf serve` with API keys.

It asks for a key and refuses a wrong one; onboards the sample mesh (OBJ + MTL + texture)
through the page and follows its progress; shows the object with its thumbnail; draws a
box on a rendered photo, estimates, and checks that the overlay and the pose appear and
equal the API's own answer to the same request; reads the service figures; then, with a
read-only key, that onboarding and deleting are unavailable and the admin-only figures are
refused with the server's reason; finally deletes the object through the confirmation
dialog. Screenshots go to $OUT (default out/console-test) at 1280×800 and at tablet width.

Usage: console/test/run.sh (installs what it needs), or with Selenium importable:
python3 console/test/browser_test.py
"""

from __future__ import annotations

import base64
import json
import math
import os
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

from selenium import webdriver
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select, WebDriverWait

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))
from reliability.server import Server, run_cli  # noqa: E402

ADMIN_KEY = "console-test-admin-key-3f9a"
READ_KEY = "console-test-read-key-77c1"
K = {"fx": 600.0, "fy": 600.0, "cx": 319.5, "cy": 239.5, "width": 640, "height": 480}
OUT = Path(os.environ.get("OUT", REPO / "out/console-test"))


def rotation(ax: float, ay: float, az: float) -> list:
    """Row-major R = Rz·Ry·Rx (radians)."""
    cx, sx, cy, sy, cz, sz = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
    rx = [[1, 0, 0], [0, cx, -sx], [0, sx, cx]]
    ry = [[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]
    rz = [[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]
    mul = lambda a, b: [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]  # noqa: E731
    return [v for row in mul(rz, mul(ry, rx)) for v in row]


def make_inputs(work: Path) -> dict:
    """The sample mesh, a photo of it rendered at a known pose, the box around it."""
    run_cli("sample", "--out", str(work / "sample"))
    (work / "camera.json").write_text(json.dumps({"cam_K": [K["fx"], 0, K["cx"], 0, K["fy"], K["cy"], 0, 0, 1], "width": K["width"], "height": K["height"]}))
    pose = {"R": rotation(0.5, -0.4, 0.3), "t": [0.01, -0.005, 0.42]}
    (work / "pose.json").write_text(json.dumps(pose))
    run_cli("render", "--mesh", str(work / "sample/sample_box.obj"), "--units", "m", "--pose", str(work / "pose.json"), "--camera", str(work / "camera.json"), "--out", str(work / "photo"))
    return {
        "mesh": work / "sample/sample_box.obj",
        "resources": [work / "sample/sample_box.mtl", work / "sample/sample_box_m0.png"],
        "photo": work / "photo/rgb.png",
        "camera": work / "camera.json",
        "mask": work / "photo/mask.png",
        "depth": work / "photo/depth.png",
        "pose": pose,
    }


def mask_rows(mask_png: Path) -> list:
    """The rows of an 8-bit greyscale PNG (as `b2tf render` writes masks), decoded with the
    standard library's zlib."""
    import struct
    import zlib

    data = mask_png.read_bytes()
    pos, idat, width, height = 8, b"", 0, 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos : pos + 8])
        body = data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and colour == 0, f"mask.png: expected 8-bit grey, got depth {depth} colour {colour}"
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    rows, prev = [], bytearray(width)
    for y in range(height):
        f, line = raw[y * (width + 1)], bytearray(raw[y * (width + 1) + 1 : (y + 1) * (width + 1)])
        for x in range(width):
            a = line[x - 1] if x else 0
            b, c = prev[x], prev[x - 1] if x else 0
            pred = [0, a, b, (a + b) // 2, min((a, b, c), key=lambda v: abs(a + b - c - v))][f]
            line[x] = (line[x] + pred) & 0xFF
        rows.append(line)
        prev = line
    return rows


def mask_box(rows: list) -> list:
    """[x, y, w, h] of the mask's non-zero pixels."""
    width = len(rows[0])
    xs = [x for row in rows for x in range(width) if row[x]]
    ys = [y for y, row in enumerate(rows) if any(row)]
    return [min(xs), min(ys), max(xs) - min(xs) + 1, max(ys) - min(ys) + 1]


def api(server: Server, method: str, path: str, key: str, body=None):
    req = urllib.request.Request(
        server.http + path, method=method, data=None if body is None else json.dumps(body).encode(), headers={"Authorization": f"Bearer {key}", "Content-Type": "application/json"}
    )
    with urllib.request.urlopen(req, timeout=300) as r:
        return json.loads(r.read() or b"null")


def browser() -> webdriver.Chrome:
    o = webdriver.ChromeOptions()
    o.binary_location = os.environ.get("CHROMIUM", "/usr/bin/chromium")
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,800", "--disable-gpu"):
        o.add_argument(a)
    o.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=o, service=Service(os.environ.get("CHROMEDRIVER", "/usr/bin/chromedriver")))


class Page:
    def __init__(self, driver: webdriver.Chrome, base: str) -> None:
        self.d, self.base = driver, base

    def by(self, id_: str):
        return self.d.find_element(By.ID, id_)

    def wait(self, what, timeout: float = 60, message: str = ""):
        # The page re-draws lists when they change: an element found a moment ago may be gone.
        return WebDriverWait(self.d, timeout, poll_frequency=0.2, ignored_exceptions=[StaleElementReferenceException]).until(lambda d: what(), message)

    def viewport(self, width: int, height: int) -> None:
        """The page's own size (the window's includes the browser's frame)."""
        self.d.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})

    def shot(self, name: str, whole_page: bool = False) -> None:
        """A screenshot of the viewport, or of the whole page's length."""
        OUT.mkdir(parents=True, exist_ok=True)
        shot = self.d.execute_cdp_cmd("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": whole_page})
        (OUT / f"{name}.png").write_bytes(base64.b64decode(shot["data"]))

    def tab(self, name: str) -> None:
        self.by(f"tab-{name}").click()
        self.wait(lambda: self.by(name).is_displayed())

    def give_key(self, key: str) -> None:
        self.wait(lambda: self.by("key-dialog").is_displayed(), message="no key prompt")
        self.by("key-input").clear()
        self.by("key-input").send_keys(key)
        self.by("key-use").click()

    def reopen(self) -> None:
        """The console afresh in this tab, its key forgotten."""
        self.d.execute_script("sessionStorage.clear()")
        self.d.get("about:blank")
        self.d.get(self.base + "/console/#objects")

    def click_fresh(self, selector: str, tries: int = 5) -> None:
        """Clicks what `selector` finds, again if the page re-drew it meanwhile."""
        for attempt in range(tries):
            try:
                self.d.find_element(By.CSS_SELECTOR, selector).click()
                return
            except StaleElementReferenceException:
                if attempt == tries - 1:
                    raise
                time.sleep(0.2)

    def notice(self) -> str:
        n = self.by("notice")
        return n.text if n.is_displayed() else ""

    def severe_logs(self) -> list:
        """The browser's errors, without the refusals this test provokes on purpose."""
        logs = self.d.get_log("browser")
        return [e["message"] for e in logs if e["level"] == "SEVERE" and not any(s in e["message"] for s in ("status of 401", "status of 403"))]


def main() -> None:
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="b2tf-console-") as tmp:
        work = Path(tmp)
        inputs = make_inputs(work)
        mask = mask_rows(inputs["mask"])
        truth_box = mask_box(mask)
        (work / "keys").write_text(f"{ADMIN_KEY} name=operator\n{READ_KEY} scopes=read name=viewer\n")
        server = Server(f"dir://{work / 'store'}", work / "server", ["--api-keys-file", str(work / "keys")])
        driver = None
        try:
            server.wait_ready()
            check_headers(server)
            driver = browser()
            page = Page(driver, server.http)
            run(page, server, inputs, mask)
            assert not page.severe_logs(), f"browser errors: {page.severe_logs()}"
        except Exception:
            if driver is not None:
                Page(driver, server.http).shot("failure")
                print(f"browser log: {driver.get_log('browser')}", file=sys.stderr)
            print(server.log_tail(), file=sys.stderr)
            raise
        finally:
            if driver is not None:
                driver.quit()
            server.stop()
    print(f"console browser test passed in {time.monotonic() - t0:.0f} s; screenshots in {OUT}")


def check_headers(server: Server) -> None:
    """The page needs no key; it comes with a strict CSP; / leads to it."""
    with urllib.request.urlopen(server.http + "/") as r:
        assert r.url.endswith("/console/"), r.url
        csp = r.headers["Content-Security-Policy"]
        assert "script-src 'self'" in csp and "unsafe-inline" not in csp and "frame-ancestors 'none'" in csp, csp
    try:
        urllib.request.urlopen(server.http + "/console/nothing.js")
        raise AssertionError("an unknown console file was served")
    except urllib.error.HTTPError as e:
        assert e.code == 404, e.code


def run(page: Page, server: Server, inputs: dict, mask: list) -> None:
    truth_box = mask_box(mask)
    d = page.d
    page.viewport(1280, 800)
    d.get(server.http + "/")
    # A wrong key is refused in the prompt; the right one names the caller.
    page.give_key("not-a-key")
    page.wait(lambda: "does not know this key" in page.by("key-error").text, message="wrong key not refused")
    page.shot("01-key-prompt")
    page.give_key(ADMIN_KEY)
    page.wait(lambda: "operator" in page.by("who").text, message="the caller is not shown")
    assert "write" in page.by("who").text

    # Onboard the sample mesh with its MTL and texture, 96 templates (quick).
    page.tab("onboard")
    page.by("onboard-id").send_keys("sample-box")
    page.by("onboard-mesh").send_keys(str(inputs["mesh"]))
    page.by("onboard-resources").send_keys("\n".join(str(p) for p in inputs["resources"]))
    Select(page.by("onboard-units")).select_by_value("m")
    Select(page.by("onboard-templates")).select_by_value("0:8")
    page.by("onboard-submit").click()
    page.wait(lambda: page.by("onboard-progress").get_attribute("data-state") in ("succeeded", "failed", "cancelled") or page.notice(), timeout=600, message="onboarding did not end")
    assert page.by("onboard-progress").get_attribute("data-state") == "succeeded", page.by("onboard-state").text + page.notice()
    assert float(page.by("onboard-bar").get_attribute("value")) == 96, page.by("onboard-bar").get_attribute("value")
    page.shot("02-onboarded")
    # A long onboarding (1944 templates) cancelled while it runs leaves nothing behind.
    page.by("onboard-id").clear()
    page.by("onboard-id").send_keys("cancelled-box")
    page.by("onboard-mesh").send_keys(str(inputs["mesh"]))
    Select(page.by("onboard-templates")).select_by_value("2:12")
    page.by("onboard-submit").click()
    page.wait(
        lambda: page.by("onboard-progress").get_attribute("data-state") == "running" and float(page.by("onboard-bar").get_attribute("value")) > 0,
        timeout=120,
        message="the onboarding made no progress",
    )
    page.by("onboard-cancel").click()
    page.wait(lambda: page.by("onboard-progress").get_attribute("data-state") == "cancelled", timeout=120, message="not cancelled")
    assert [o["id"] for o in api(server, "GET", "/v1/objects", ADMIN_KEY)["objects"]] == ["sample-box"]

    # The object's card, with a thumbnail drawn by the server.
    page.tab("objects")
    card = '.card[data-object="sample-box"]'
    page.wait(lambda: d.execute_script(f"return document.querySelector('{card} img')?.naturalWidth") == 160, message="no thumbnail")
    text = page.wait(lambda: d.find_element(By.CSS_SELECTOR, card).text)
    assert "96" in text and "Symmetries" in text, text
    page.shot("03-objects")

    # A photo, the camera, a box dragged on the canvas; estimate.
    page.tab("photo")
    page.by("photo-file").send_keys(str(inputs["photo"]))
    page.wait(lambda: page.by("photo-cx").get_attribute("value") == "319.5", message="photo not loaded")
    # The intrinsics from the camera file the photo was rendered with (the CLI's format).
    page.by("photo-camera-file").send_keys(str(inputs["camera"]))
    page.wait(lambda: page.by("photo-fx").get_attribute("value") == "600" and page.by("photo-fy").get_attribute("value") == "600", message="camera file not read")
    drag_box(page, truth_box)
    drawn = [int(page.by(f"photo-box-{c}").get_attribute("value")) for c in "xywh"]
    assert all(abs(a - b) <= 3 for a, b in zip(drawn, truth_box)), (drawn, truth_box)
    page.by("photo-estimate").click()
    page.wait(lambda: page.by("photo-result").is_displayed() or page.notice(), timeout=300, message="no answer")
    assert not page.notice(), page.notice()
    page.wait(lambda: d.execute_script("return document.getElementById('photo-overlay').naturalWidth") == 640, message="no overlay")
    row = d.find_element(By.CSS_SELECTOR, "#photo-results tbody tr")
    shown_t = [float(v) for v in row.find_element(By.CLASS_NAME, "t").text.split(",")]
    shown_q = [float(v) for v in row.find_element(By.CLASS_NAME, "q").text.split(",")]
    assert "curl" in page.by("photo-curl").text and "b2tfpose.Client" in page.by("photo-python").text
    assert d.execute_script("return document.getElementById('photo-download').href").startswith("blob:")
    page.shot("04-photo-estimated", whole_page=True)

    # The API's own answer to the same request is the one the page shows.
    request = {
        "image": {"encoded": base64.b64encode(inputs["photo"].read_bytes()).decode()},
        "intrinsics": K,
        "detections": [{"object_id": "sample-box", "bbox": drawn}],
        "options": {"rrc": True, "verify": True},
    }
    answer = api(server, "POST", "/v1/estimate", ADMIN_KEY, request)["results"][0]
    api_t = [v * 1000 for v in answer["pose"]["t"]]
    assert all(abs(a - b) < 0.06 for a, b in zip(shown_t, api_t)), (shown_t, api_t)
    assert all(abs(a - b) < 1e-3 for a, b in zip(shown_q, answer["pose"]["quaternion_wxyz"])), (shown_q, answer["pose"]["quaternion_wxyz"])
    # The runner-up as the API gives it: how much it lost by, how far it is.
    up, cell = answer.get("runner_up"), row.find_element(By.CLASS_NAME, "runner-up").text
    assert (up is None and cell == "–") or (up is not None and f"lost by {up['margin']:.3f}" in cell and f"{up['distance_over_diameter']:.2f}·d" in cell), (cell, up)
    # A close call is noted where, and only where, the server says it is one.
    noted = "a close call" in row.find_element(By.CLASS_NAME, "note").text
    assert noted == bool(up and up["close_call"]), (noted, up)
    err_mm = math.dist(api_t, [v * 1000 for v in inputs["pose"]["t"]])
    print(f"the page's pose equals the API's; its translation is {err_mm:.1f} mm from the truth")

    # With the depth the photo was rendered with (16-bit, 0.1 mm units): the note says how
    # the pose's surface lies on the measured one, and the curl and Python forms send it.
    page.by("photo-depth").send_keys(str(inputs["depth"]))
    page.by("photo-depth-scale").clear()
    page.by("photo-depth-scale").send_keys("0.1")
    page.by("photo-estimate").click()
    page.wait(lambda: page.by("photo-estimate").is_enabled() and page.by("photo-result").is_displayed() or page.notice(), timeout=300, message="no answer with depth")
    assert not page.notice(), page.notice()
    row = d.find_element(By.CSS_SELECTOR, "#photo-results tbody tr")
    note = row.find_element(By.CLASS_NAME, "note").text
    assert "depth: " in note and "mm RMS" in note, note
    depth_t = [float(v) for v in row.find_element(By.CLASS_NAME, "t").text.split(",")]
    assert math.dist(depth_t, [v * 1000 for v in inputs["pose"]["t"]]) < 5, depth_t
    curl, python = page.by("photo-curl").text, page.by("photo-python").text
    assert "DEPTH=$(base64 -w0 'depth.png')" in curl and '"scale_mm":0.1' in curl, curl
    assert 'depth="depth.png", depth_scale=0.1' in python, python
    print(f"with depth: {note}")
    d.execute_script("document.getElementById('photo-depth').value = ''")

    # A painted mask instead of the box: strokes across the object.
    page.by("photo-clear").click()
    d.find_element(By.CSS_SELECTOR, 'input[name="mode"][value="mask"]').click()
    paint(page, mask)
    # Verification settings: a value out of range is stopped in the page (no request); the
    # ones given go into the request and into its curl and Python forms.
    d.find_element(By.CSS_SELECTOR, "#photo-settings summary").click()
    page.by("photo-nudge").send_keys("50")
    page.by("photo-estimate").click()
    assert page.by("photo-estimate").is_enabled() and page.by("photo-result").is_displayed(), "a request with a nudge of 50°"
    assert not d.execute_script("return document.getElementById('photo-nudge').validity.valid")
    page.by("photo-nudge").clear()
    page.by("photo-nudge").send_keys("12")
    page.by("photo-spin-steps").send_keys("4")
    page.by("photo-depth-views").send_keys("2")
    Select(page.by("photo-refiner")).select_by_value("contour")
    Select(page.by("photo-box-prior")).select_by_value("true")
    Select(page.by("photo-rrc-always")).select_by_value("true")
    page.by("photo-estimate").click()
    # Busy at once, before the mask is encoded, with the box's answer put away: no second
    # request from a second click, and no old answer read as the new one.
    assert not page.by("photo-estimate").is_enabled() and not page.by("photo-result").is_displayed()
    page.wait(lambda: page.by("photo-estimate").is_enabled(), timeout=300, message="no answer from the mask")
    assert not page.notice(), page.notice()
    assert "pose(s) found" in page.by("photo-summary").text and "sample-box" in page.by("photo-results").text
    assert "$MASK" in page.by("photo-curl").text and "mask=" in page.by("photo-python").text
    curl, python = page.by("photo-curl").text, page.by("photo-python").text
    assert all(o in curl for o in ('"nudge_degrees":12', '"spin_steps":4', '"depth_views":2', '"refiner":"contour"', '"box_prior":true', '"rrc_always":true')) and "verify_templates" not in curl, curl
    assert all(o in python for o in ("nudge_degrees=12", "spin_steps=4", "depth_views=2", 'refiner="contour"', "box_prior=True", "rrc_always=True")), python
    masked_t = [float(v) for v in d.find_element(By.CSS_SELECTOR, "#photo-results tbody tr .t").text.split(",")]
    assert math.dist(masked_t, [v * 1000 for v in inputs["pose"]["t"]]) < 20, masked_t
    page.shot("05-photo-mask")
    for setting in ("photo-nudge", "photo-spin-steps", "photo-depth-views"):
        page.by(setting).clear()
    Select(page.by("photo-refiner")).select_by_value("")
    Select(page.by("photo-box-prior")).select_by_value("")
    Select(page.by("photo-rrc-always")).select_by_value("")
    # The detector: no box, no mask.
    d.find_element(By.CSS_SELECTOR, 'input[name="mode"][value="detect"]').click()
    page.by("photo-estimate").click()
    page.wait(lambda: not page.by("photo-estimate").is_enabled(), timeout=10)
    page.wait(lambda: page.by("photo-estimate").is_enabled(), timeout=300, message="the detect estimate did not end")
    assert not page.notice(), page.notice()
    assert '"objects":["sample-box"]' in page.by("photo-curl").text, page.by("photo-curl").text
    print(f"detect mode: {page.by('photo-summary').text}")

    # The same page at tablet width.
    page.viewport(820, 1180)
    page.shot("06-photo-tablet")
    page.viewport(1280, 800)

    # Service figures (admin key): the estimate is counted.
    page.tab("service")
    # Routes with ids in their template are listed too (their labels hold braces).
    page.wait(lambda: all(e in page.by("service-requests").text for e in ("POST /v1/estimate", "GET /v1/operations/{id}", "GET /v1/objects/{id}/thumbnail")), message="request figures missing")
    page.shot("07-service")

    # A read-only key: no onboarding, no deleting, the admin figures refused with the reason.
    page.reopen()
    page.give_key(READ_KEY)
    page.wait(lambda: "viewer" in page.by("who").text, message="read key not accepted")
    page.wait(lambda: not d.find_element(By.CSS_SELECTOR, '.card[data-object="sample-box"] button.danger').is_enabled(), message="a read key may delete")
    page.tab("onboard")
    assert not page.by("onboard-submit").is_enabled(), "a read key may onboard"
    assert not page.by("onboard-progress").is_displayed(), "an onboarding's progress shown before any"
    assert "lacks the write scope" in page.by("onboard-denied").text
    page.shot("08-read-key-onboard")
    page.tab("service")
    page.wait(lambda: "lacks the `admin` scope" in page.by("service-metrics-note").text, message="metrics not refused")

    # Back to the operator key: delete through the confirmation dialog.
    page.reopen()
    page.give_key(ADMIN_KEY)
    page.wait(lambda: d.find_elements(By.CSS_SELECTOR, '.card[data-object="sample-box"]'), message="no card")
    page.click_fresh('.card[data-object="sample-box"] button.danger')
    page.wait(lambda: page.by("confirm-dialog").is_displayed())
    page.by("confirm-yes").click()
    page.wait(lambda: not d.find_elements(By.CSS_SELECTOR, '.card[data-object="sample-box"]'), message="the object stayed")
    assert api(server, "GET", "/v1/objects", ADMIN_KEY)["objects"] == []


def canvas_offsets(page: Page):
    """A function from image pixels to offsets from the canvas's centre on the screen."""
    canvas = page.by("photo-canvas")
    page.d.execute_script("arguments[0].scrollIntoView({block: 'center'})", canvas)
    w, h = page.d.execute_script("const r = arguments[0].getBoundingClientRect(); return [r.width, r.height]", canvas)
    return canvas, lambda x, y: (round(x * w / K["width"] - w / 2), round(y * h / K["height"] - h / 2))


def paint(page: Page, mask: list) -> None:
    """Brush strokes across the object, every few rows, a little inside its outline (as a
    careful hand would)."""
    canvas, to = canvas_offsets(page)
    covered = [y for y, row in enumerate(mask) if any(row)]
    for y in range(covered[0] + 6, covered[-1] - 5, 8):
        xs = [x for x, v in enumerate(mask[y]) if v]
        if xs[-1] - xs[0] < 16:
            continue
        (a, b), (c, _) = to(xs[0] + 6, y), to(xs[-1] - 6, y)
        ActionChains(page.d).move_to_element_with_offset(canvas, a, b).click_and_hold().move_by_offset((c - a) // 2, 0).move_by_offset(c - a - (c - a) // 2, 0).release().perform()


def drag_box(page: Page, box: list) -> None:
    """Drags on the canvas from the box's top-left to its bottom-right corner (image
    pixels mapped to where the canvas is drawn)."""
    canvas, to = canvas_offsets(page)
    x0, y0 = to(box[0], box[1])
    x1, y1 = to(box[0] + box[2], box[1] + box[3])
    ActionChains(page.d).move_to_element_with_offset(canvas, x0, y0).click_and_hold().move_by_offset((x1 - x0) // 2, (y1 - y0) // 2).move_by_offset(
        x1 - x0 - (x1 - x0) // 2, y1 - y0 - (y1 - y0) // 2
    ).release().perform()


if __name__ == "__main__":
    main()
