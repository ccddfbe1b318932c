"""Derives the orthophoto test files from Debian r-cran-stars 0.6-0-4's
/usr/lib/R/site-library/stars/tif/L7_ETMs.tif (a Landsat 7 ETM+ scene of Olinda, Brazil, 6 bands,
uint8, 349 x 352 pixels of 28.5 m, SIRGAS 2000 / UTM 25S, EPSG:31985), the same package that ships
the DEM ../../../../shared/data/dem/olinda_dem_utm25s.tif (same north-west corner).

True colour = ETM+ bands 3 (red), 2 (green), 1 (blue); each band is stretched linearly from its
2nd to its 98th percentile onto 0..255 (the raw digital numbers use ~60 of 256 levels, so the
unstretched image is nearly uniform grey-blue). Nothing else is changed: same pixels, same
georeferencing tags (ModelPixelScale, ModelTiepoint, GeoKeyDirectory, GeoAsciiParams) copied
verbatim.

Usage: python3 derive.py L7_ETMs.tif   (needs numpy, tifffile, pillow)
"""
import sys

import numpy as np
import tifffile
from PIL import Image

src = tifffile.TiffFile(sys.argv[1])
page = src.pages[0]
bands = page.asarray()  # (rows, cols, 6)
rgb = bands[:, :, [2, 1, 0]].astype(np.float64)
out = np.empty(rgb.shape, np.uint8)
for c in range(3):
    lo, hi = np.percentile(rgb[:, :, c], [2, 98])
    out[:, :, c] = np.clip((rgb[:, :, c] - lo) / (hi - lo) * 255.0 + 0.5, 0, 255).astype(np.uint8)

extratags = []
for code in (33550, 33922, 34735, 34736, 34737):
    tag = page.tags.get(code)
    if tag is None:
        continue
    dtype = {33550: 12, 33922: 12, 34735: 3, 34736: 12, 34737: 2}[code]
    value = tag.value
    count = len(value) if not isinstance(value, str) else len(value) + 1
    extratags.append((code, dtype, count, value, False))
tifffile.imwrite(
    "olinda_l7_rgb_utm25s.tif",
    out,
    photometric="rgb",
    compression="adobe_deflate",
    extratags=extratags,
)
Image.fromarray(out).save("olinda_l7_rgb.png", optimize=True)
Image.fromarray(out).save("olinda_l7_rgb.jpg", quality=90)
