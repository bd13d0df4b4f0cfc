"""experiments.conv_gops: every format and int8 backend measured at a tiny shape."""

import torch

from experiments.conv_gops import conv_gops


def test_conv_gops_measures_every_format():
    threads = torch.get_num_threads()
    try:
        (row,) = conv_gops(shapes=((4, 8, 8),), batch=2, work=1e6)
    finally:
        torch.set_num_threads(threads)
    assert (row["cin"], row["cout"], row["side_px"]) == (4, 8, 8)
    assert {"bf16", "fp32", "int8 qconv2d_pointwise"} <= set(row) and "int8 qnnpack" not in row
    assert all(v > 0 for k, v in row.items() if k not in ("cin", "cout", "side_px"))
