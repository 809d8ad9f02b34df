"""Which EGL device a GPU renders on: the devices this machine's libEGL lists, and the matching rule
for NVIDIA machines whose EGL order is not CUDA's (device lists built here, as such a machine's driver
reports them)."""

import pytest

from renderer.cli import main
from renderer.errors import GLContextError
from renderer.gpu.context import GLContext
from renderer.gpu.egl_devices import EGLDevice, egl_devices, egl_index_for_gpu

NV = ("EGL_NV_device_cuda", "EGL_EXT_device_drm")
MESA = ("EGL_MESA_device_software",)


def nvidia(index, cuda):
    return EGLDevice(index, NV, cuda, f"/dev/dri/card{index}")


def test_this_machines_devices_are_listed_in_order_with_their_kind():
    devices = egl_devices()
    assert devices and [d.index for d in devices] == list(range(len(devices)))
    for d in devices:
        assert d.kind in ("nvidia", "software", "other")
        assert (d.cuda_device is not None) == (d.kind == "nvidia")
        assert d.describe().startswith(f"EGL device {d.index} ({d.kind}")


def test_a_gpu_is_found_by_its_cuda_ordinal_not_by_its_number_as_an_index():
    devices = [nvidia(0, 1), nvidia(1, 0), EGLDevice(2, MESA, None, None)]   # EGL lists CUDA 1 first
    assert egl_index_for_gpu(0, devices, None)[0] == 1
    assert egl_index_for_gpu(1, devices, None)[0] == 0
    assert egl_index_for_gpu(1, devices, ["0", "1"])[0] == 0


def test_ray_s_mask_makes_the_replica_s_gpu_cuda_device_0():
    # Ray gave this process GPU 3: CUDA_VISIBLE_DEVICES=3, and a masking driver reports it as CUDA 0.
    devices = [EGLDevice(0, MESA, None, None), nvidia(1, 0)]
    index, how = egl_index_for_gpu(3, devices, ["3"])
    assert index == 1 and "CUDA device 0" in how and "CUDA_VISIBLE_DEVICES" in how
    # Two GPUs given, the second asked for.
    assert egl_index_for_gpu(5, [nvidia(0, 1), nvidia(1, 0)], ["2", "5"])[0] == 0


def test_a_driver_that_ignores_the_mask_is_matched_by_the_physical_id():
    devices = [nvidia(0, 2), nvidia(1, 3), nvidia(2, 0), nvidia(3, 1)]   # four reported, one visible
    index, how = egl_index_for_gpu(3, devices, ["3"])
    assert index == 1 and "physical" in how


def test_no_match_names_the_gpu_and_every_device():
    with pytest.raises(GLContextError, match=r"GPU 2 \(CUDA device 2.*EGL device 0 \(nvidia, CUDA device 0"):
        egl_index_for_gpu(2, [nvidia(0, 0), nvidia(1, 1)], None)
    with pytest.raises(GLContextError, match=r"GPU 4 was asked for, but EGL lists 1 device"):
        egl_index_for_gpu(4, [EGLDevice(0, MESA, None, None)], None)


def test_without_cuda_reporting_the_number_is_the_index():
    index, how = egl_index_for_gpu(0, [EGLDevice(0, MESA, None, None)], ["0"])
    assert index == 0 and "by index" in how


def test_the_context_takes_its_gpu_from_the_environment_and_says_how(monkeypatch):
    monkeypatch.delenv("GARMENT_RENDER_EGL_DEVICE", raising=False)
    monkeypatch.setenv("GARMENT_RENDER_GPU", "0")
    gl = GLContext()
    try:
        assert gl.device_index == 0
        assert gl.info()["device"].startswith("EGL device 0 for GPU 0:")
    finally:
        gl.release()
    monkeypatch.setenv("GARMENT_RENDER_GPU", str(len(egl_devices()) + 3))
    with pytest.raises(GLContextError, match="GPU"):
        GLContext()


def test_devices_command_lists_devices_and_opens_the_chosen_one(capsys):
    assert main(["devices", "--gpu", "0"]) == 0
    out = capsys.readouterr().out
    assert "EGL device 0 (" in out and "GPU 0: EGL device" in out and "renders on" in out
    assert main(["devices", "--gpu", "99"]) == 2
    assert "GPU 99" in capsys.readouterr().err
