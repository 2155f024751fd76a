"""Reading the package's HTML pages in tests (brdf_fit.report): the images, scripts, outside
references and table cells of a page, and an embedded PNG decoded."""

import base64
import html.parser
import io

import matplotlib.image
import numpy as np


class Page(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.images, self.scripts, self.links, self.cells = [], 0, [], []
        self._in_cell = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag == "script":
            self.scripts += 1
        for key in ("href", "src"):
            if key in a and tag != "img":
                self.links.append(a[key])
        if tag == "td":
            self._in_cell = True
            self.cells.append("")

    def handle_endtag(self, tag):
        if tag == "td":
            self._in_cell = False

    def handle_data(self, data):
        if self._in_cell:
            self.cells[-1] += data


def decoded(src: str) -> np.ndarray:
    assert src.startswith("data:image/png;base64,"), src[:40]
    return matplotlib.image.imread(io.BytesIO(base64.b64decode(src.split(",", 1)[1])),
                                   format="png")
