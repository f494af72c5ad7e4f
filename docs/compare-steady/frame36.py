"""What residual_noise.py and landed_worth.py share: reading a frame, its luminance, and the
regions of `vase` frame 36 they report (boxes of the 320x240 frame with the edge pixels, the 7%
of highest relative gradient of the reference, taken out; and the edge pixels themselves)."""
import numpy as np
import OpenImageIO as oiio


def read(path):
    i = oiio.ImageInput.open(path)
    spec = i.spec()
    a = np.asarray(i.read_image(format="float"))
    names = list(spec.channelnames)
    i.close()
    return a.reshape(spec.height, spec.width, len(names)), names


def luminance(a):
    return a[..., :3] @ np.array([0.2126, 0.7152, 0.0722])


def regions(ref):
    """The regions of frame 36, as masks over `ref` (the reference's luminance)."""
    gy, gx = np.gradient(ref)
    grad = np.hypot(gx, gy) / (ref + 0.05)
    edge = grad > np.quantile(grad, 0.93)

    def box(x0, y0, x1, y1):
        m = np.zeros(ref.shape, bool)
        m[y0:y1, x0:x1] = True
        return m & ~edge

    return {
        "back wall": box(10, 5, 310, 60),
        "glossy vase": box(145, 95, 176, 145),
        "floor in the shadow of the table": box(60, 200, 260, 236),
        "table top": box(180, 158, 262, 178),
        "silhouettes and edges": edge,
        "whole frame": np.ones(ref.shape, bool),
    }
