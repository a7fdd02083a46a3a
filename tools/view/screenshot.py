#!/usr/bin/env python3
"""Screenshot of a running `sylva view` page in headless Chromium (Debian's chromium and
chromium-driver), for the docs: the README's image is made with

    sylva view demo --port 8080 &          # prints the URL with its token
    python3 tools/view/screenshot.py URL docs/images/viewer.png --sun 35 200 --samples 8

It sets the sun on the compass (elevation, compass azimuth), waits for a refined frame with
at least --samples samples per pixel, and saves the page. Standard library only: WebDriver is
JSON over HTTP."""
import argparse
import base64
import http.client
import json
import shutil
import socket
import subprocess
import sys
import time


def call(port, method, path, body=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=600)
    data = json.dumps(body) if body is not None else None
    conn.request(method, path, body=data, headers={"Content-Type": "application/json"})
    value = json.loads(conn.getresponse().read())["value"]
    conn.close()
    if isinstance(value, dict) and "error" in value:
        raise RuntimeError(f"{method} {path}: {value}")
    return value


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("url")
    p.add_argument("output")
    p.add_argument("--size", default="1280,800", help="window WIDTH,HEIGHT")
    p.add_argument("--sun", nargs=2, type=float, metavar=("ELEVATION", "AZIMUTH"))
    p.add_argument("--samples", type=int, default=4)
    p.add_argument("--timeout", type=float, default=600)
    a = p.parse_args()
    for tool in ("chromium", "chromedriver"):
        if not shutil.which(tool):
            sys.exit(f"{tool} is not installed (Debian: apt-get install chromium chromium-driver)")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    driver = subprocess.Popen(["chromedriver", f"--port={port}"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        for _ in range(300):
            try:
                call(port, "GET", "/status")
                break
            except OSError:
                time.sleep(0.1)
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {
            "binary": shutil.which("chromium"),
            "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                     f"--window-size={a.size}", "--force-device-scale-factor=1"]}}}}
        session = call(port, "POST", "/session", caps)["sessionId"]
        s = f"/session/{session}"
        run = lambda js: call(port, "POST", s + "/execute/sync", {"script": js, "args": []})
        call(port, "POST", s + "/url", {"url": a.url})
        deadline = time.time() + a.timeout

        def wait(js, what):
            while not run(js):
                if time.time() > deadline:
                    sys.exit(f"timed out waiting for {what}")
                time.sleep(0.2)

        wait("return Number(document.getElementById('frame').dataset.frames || 0) > 0",
             "the first frame")
        if a.sun:
            # The page's own state and request path, as a drag on the compass ends.
            run(f"state.sun = {{by: 'angles', elevation: {a.sun[0]}, azimuth: {a.sun[1]}}};"
                f"state.sunShown = {{elevation: {a.sun[0]}, azimuth: {a.sun[1]}}};"
                "drawCompass(); request(false); return true;")
            time.sleep(0.5)
        wait("const t = document.getElementById('stat-samples').textContent;"
             f"return !t.includes('preview') && parseInt(t) >= {a.samples}",
             f"{a.samples} samples per pixel")
        png = base64.b64decode(call(port, "GET", s + "/screenshot"))
        with open(a.output + ".tmp", "wb") as f:
            f.write(png)
        import os
        os.replace(a.output + ".tmp", a.output)
        call(port, "DELETE", s)
        print(f"wrote {a.output}")
    finally:
        driver.kill()


if __name__ == "__main__":
    main()
