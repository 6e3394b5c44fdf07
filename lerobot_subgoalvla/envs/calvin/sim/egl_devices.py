"""Which EGL device renders: pybullet's EGL plugin takes the index in ``EGL_VISIBLE_DEVICES``.

pybullet's ``eglRenderer`` plugin enumerates the EGL devices (``eglQueryDevicesEXT``) and renders on the one
whose index ``EGL_VISIBLE_DEVICES`` holds (0 when unset). An index past the last device makes the plugin
print "Invalid render_device choice" and end the whole process, so we check it before loading the plugin.

On an NVIDIA machine the EGL device order need not follow the CUDA order. calvin_env therefore maps the CUDA
device its policy runs on to the EGL device of the same GPU (the ``EGL_CUDA_DEVICE_NV`` attribute of
``EGL_NV_device_cuda``), so that evaluation workers on several GPUs each render on their own. We do the same
with ctypes against ``libEGL.so.1`` (no compiled helper): :func:`egl_devices` lists the devices with their
CUDA index (None for devices that are no CUDA GPU, e.g. Mesa's llvmpipe), :func:`select_egl_device` sets
``EGL_VISIBLE_DEVICES`` for a CUDA device or checks the value already there.
"""

from __future__ import annotations

import ctypes
import logging
import os
from dataclasses import dataclass

logger = logging.getLogger(__name__)

VISIBLE_DEVICES_VAR = "EGL_VISIBLE_DEVICES"
#: EGL_EXT_device_query / EGL_NV_device_cuda constants (Khronos eglext.h).
_EGL_CUDA_DEVICE_NV = 0x323A
_EGL_EXTENSIONS = 0x3055
_MAX_DEVICES = 32


@dataclass(frozen=True)
class EglDevice:
    """One EGL device: its index (what ``EGL_VISIBLE_DEVICES`` takes) and, for a CUDA GPU, its CUDA index."""

    index: int
    cuda_index: int | None
    extensions: str


def _load_functions() -> tuple:
    try:
        egl = ctypes.CDLL("libEGL.so.1")
    except OSError as err:
        raise RuntimeError(
            "renderer='egl': libEGL.so.1 not found (on Debian: apt-get install libegl1 libegl-mesa0 "
            "libgl1-mesa-dri; with NVIDIA: the driver's EGL)"
        ) from err
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]

    def extension(name: str, *signature):
        address = egl.eglGetProcAddress(name.encode())
        return ctypes.CFUNCTYPE(*signature)(address) if address else None

    query_devices = extension(
        "eglQueryDevicesEXT", ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p),
        ctypes.POINTER(ctypes.c_int),
    )  # fmt: skip
    query_string = extension("eglQueryDeviceStringEXT", ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int)
    query_attrib = extension(
        "eglQueryDeviceAttribEXT",
        ctypes.c_uint,
        ctypes.c_void_p,
        ctypes.c_int,
        ctypes.POINTER(ctypes.c_ssize_t),
    )
    return query_devices, query_string, query_attrib


def egl_devices() -> list[EglDevice]:
    """The EGL devices in the order pybullet's plugin indexes them; [] when the driver cannot enumerate."""
    query_devices, query_string, query_attrib = _load_functions()
    if query_devices is None:
        return []
    handles = (ctypes.c_void_p * _MAX_DEVICES)()
    count = ctypes.c_int(0)
    if not query_devices(_MAX_DEVICES, handles, ctypes.byref(count)):
        return []
    devices = []
    for index in range(count.value):
        raw = query_string(handles[index], _EGL_EXTENSIONS) if query_string is not None else None
        extensions = raw.decode() if raw else ""
        cuda = ctypes.c_ssize_t(-1)
        has_cuda = "EGL_NV_device_cuda" in extensions and query_attrib is not None
        if has_cuda and query_attrib(handles[index], _EGL_CUDA_DEVICE_NV, ctypes.byref(cuda)):
            devices.append(EglDevice(index, int(cuda.value), extensions))
        else:
            devices.append(EglDevice(index, None, extensions))
    return devices


def choose_index(devices: list[EglDevice], cuda_device: int | None, visible: str | None) -> int:
    """The EGL device index to render on.

    Args:
        devices: :func:`egl_devices`.
        cuda_device: Render on the GPU of this CUDA device; None keeps ``visible``.
        visible: The current value of ``EGL_VISIBLE_DEVICES`` (None: unset, which means device 0).

    Raises:
        ValueError: naming the devices found, when the choice does not exist.
    """
    names = [f"{d.index} (CUDA {d.cuda_index})" if d.cuda_index is not None else f"{d.index} (no CUDA)"
             for d in devices]  # fmt: skip
    found = ", ".join(names) or "none"
    if cuda_device is None:
        value = visible if visible not in (None, "") else "0"
        if not value.isdigit() or int(value) >= max(len(devices), 1):
            raise ValueError(
                f"{VISIBLE_DEVICES_VAR}={value!r} names no EGL device (found: {found}); unset it or use one "
                "of the indices"
            )
        return int(value)
    for device in devices:
        if device.cuda_index == cuda_device:
            return device.index
    raise ValueError(
        f"--env.egl_cuda_devices: CUDA device {cuda_device} is no EGL device (EGL devices: {found}); drop "
        "the flag to render on EGL device 0, or list the CUDA indices shown"
    )


def select_egl_device(cuda_device: int | None) -> int:
    """Set ``EGL_VISIBLE_DEVICES`` for ``cuda_device`` (or check its current value); returns the index.

    Call it in the process that loads the EGL plugin, before loading it.
    """
    devices = egl_devices()
    index = choose_index(devices, cuda_device, os.environ.get(VISIBLE_DEVICES_VAR))
    os.environ[VISIBLE_DEVICES_VAR] = str(index)
    logger.debug("EGL device %d of %d (CUDA device %s)", index, len(devices), cuda_device)
    return index
