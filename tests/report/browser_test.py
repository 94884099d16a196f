#!/usr/bin/python3
"""The calibration report as an operator opens it: headless Chromium, 1280 px wide.

Renders the MINI example (scripts/report-example.sh: cdpr-fit diagnose on a recording with a
concealed force-sensor gain error) and checks, in the browser:
  - no console message and no page error, and nothing fetched (a Content-Security-Policy that
    allows no network is added to a copy of the page; a violation is an error);
  - the verdict, the next step, the named-effects table and the key figures end within the
    first 1,000 px;
  - every plot (svg.plot) has a text alternative (<title> and <desc>, aria-label) and a
    non-empty drawing: data marks (elements with a tooltip) with a non-zero extent.
A small inline script, added to the copy only, measures after the load event and writes the
figures into the DOM, which `chromium --dump-dom` prints.

Exit status: 0 passed, 1 failed, 77 skipped (CTest SKIP_RETURN_CODE) when chromium is not
installed (Debian package chromium; scripts/install-deps.sh installs it).
    browser_test.py CDPR_FIT SOURCE_DIR
"""
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

PROBE = r"""
<meta http-equiv="Content-Security-Policy"
      content="default-src 'none'; style-src 'unsafe-inline'; script-src 'unsafe-inline'">
<script>
window.__problems = [];
window.addEventListener('error', e => window.__problems.push('error: ' + (e.message ||
    (e.target && (e.target.src || e.target.href)) || 'resource')), true);
document.addEventListener('securitypolicyviolation',
    e => window.__problems.push('fetch blocked: ' + e.blockedURI));
for (const level of ['error', 'warn']) {
  const original = console[level];
  console[level] = (...a) => { window.__problems.push('console.' + level + ': ' + a.join(' '));
                               original.apply(console, a); };
}
window.addEventListener('load', () => {
  const bottom = id => { const e = document.getElementById(id);
                         return e ? e.getBoundingClientRect().bottom + window.scrollY : null; };
  const plots = [...document.querySelectorAll('svg.plot')].map(svg => {
    const marks = [...svg.querySelectorAll('circle,rect,ellipse,polygon,line,g')]
        .filter(m => m.querySelector(':scope > title'));
    const drawn = marks.filter(m => { const b = m.getBBox(); return b.width > 0 || b.height > 0; });
    const box = svg.getBoundingClientRect();
    return {label: svg.getAttribute('aria-label') || '',
            title: (svg.querySelector(':scope > title') || {}).textContent || '',
            desc: (svg.querySelector(':scope > desc') || {}).textContent || '',
            width: box.width, height: box.height, marks: marks.length, drawn: drawn.length};
  });
  const out = {verdict: bottom('verdict'), next_step: bottom('next-step'),
               effects: bottom('effects'), key_figures: bottom('key-figures'),
               scripts: document.scripts.length, plots: plots, problems: window.__problems};
  const pre = document.createElement('pre');
  pre.id = 'probe';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>
"""


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__, file=sys.stderr)
        return 2
    fit, source = Path(sys.argv[1]).resolve(), Path(sys.argv[2]).resolve()
    chromium = shutil.which("chromium")
    if chromium is None:
        print("SKIPPED: chromium is not installed (Debian package chromium; "
              "bash scripts/install-deps.sh installs it)")
        return 77
    failures = []
    with tempfile.TemporaryDirectory(prefix="report_browser_") as tmp:
        example = Path(tmp) / "example"
        subprocess.run(["bash", str(source / "scripts/report-example.sh"), str(fit), str(example)],
                       check=True)
        page = (example / "report.html").read_text(encoding="utf-8")
        if "<script" in page:
            failures.append("the report itself carries a script")
        if re.search(r"""(src|href)=["']?(https?:)?//""", page):
            failures.append("the report refers to a network resource")
        probed = example / "probed.html"
        probed.write_text(page.replace("<head>", "<head>" + PROBE, 1), encoding="utf-8")
        # --no-sandbox: Chromium refuses its sandbox as root (CI containers). Console messages
        # go to stderr with --enable-logging=stderr ("CONSOLE(line)").
        run = subprocess.run(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
             "--window-size=1280,1000", "--virtual-time-budget=10000", "--enable-logging=stderr",
             "--v=0", "--dump-dom", probed.as_uri()],
            capture_output=True, text=True, timeout=180)
        for line in run.stderr.splitlines():
            if re.search(r":CONSOLE[:(]", line) or "Uncaught" in line:
                failures.append("console: " + line.strip())
        m = re.search(r'<pre id="probe">(.*?)</pre>', run.stdout, re.S)
        if m is None:
            print(run.stderr[-3000:], file=sys.stderr)
            print("FAILED: the probe did not run (no measurements in the DOM)")
            return 1
        text = m.group(1).replace("&quot;", '"').replace("&lt;", "<").replace("&gt;", ">")
        probe = json.loads(text.replace("&amp;", "&"))

    print("measured:", json.dumps({k: v for k, v in probe.items() if k != "plots"}))
    for problem in probe["problems"]:
        failures.append(problem)
    if probe["scripts"] != 1:
        failures.append(f"{probe['scripts']} scripts in the page (only the probe expected)")
    for what in ("verdict", "next_step", "effects", "key_figures"):
        where = probe[what]
        if where is None:
            failures.append(f"{what}: not on the page")
        elif where > 1000:
            failures.append(f"{what}: ends at {where:.0f} px, below the first 1,000 px")
    plots = probe["plots"]
    # The MINI example: two heat maps, at least one residual plot, two anchor views, two pose views.
    if len(plots) < 7:
        failures.append(f"{len(plots)} plots, expected at least 7")
    for p in plots:
        name = p["label"] or "(unnamed plot)"
        print(f"plot: {name}: {p['drawn']} of {p['marks']} marks drawn, "
              f"{p['width']:.0f} x {p['height']:.0f} px")
        if not p["label"] or not p["title"] or not p["desc"]:
            failures.append(f"{name}: no text alternative (aria-label, <title>, <desc>)")
        if p["width"] <= 0 or p["height"] <= 0:
            failures.append(f"{name}: not laid out")
        if p["drawn"] == 0:
            failures.append(f"{name}: empty drawing")
    if failures:
        for f in failures:
            print("FAILED:", f)
        return 1
    print(f"passed: {len(plots)} plots drawn, the decision within "
          f"{max(probe['verdict'], probe['effects'], probe['key_figures']):.0f} px")
    return 0


if __name__ == "__main__":
    sys.exit(main())
