"""pythonfmu's C++ wrapper (libpythonfmu-export.so), corrected: built from pinned
sources with patches/pythonfmu/*.patch, for FaceFMU and any other FMU that pythonfmu 0.7.0
builds.

pythonfmu 0.7.0's own wrapper reads and writes freed heap memory when the importer's
process exits (glibc then aborts it, "corrupted double-linked list", exit code 134;
patches/pythonfmu/README.md, docs/dev-notes/exit-crash.md). The corrected one is built
from the wrapper sources of the pythonfmu 0.6.9 sdist (from PyPI, sha256-pinned) with the
patches applied (0001 is upstream's change that made 0.7.0's wrapper), with the C++
compiler and Python headers found here; built once (on first use, with the sdist's
download) and cached under ~/.cache/facefmu/pythonfmu-wrapper ($FACEFMU_CACHE_DIR or
$XDG_CACHE_HOME move it). $FACEFMU_PYTHONFMU_SDIST may name a local copy of the sdist
(offline machines). Used at build time only (build_fmu.py), from a checkout: the patches
are read from the repository's patches/ folder.
"""

import hashlib
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import tempfile
import zipfile
from pathlib import Path

from solver.core._cache import user_cache_dir

ROOT = Path(__file__).resolve().parents[1]
PATCHES = ROOT / "patches" / "pythonfmu"
WRAPPER_FOR = "0.7.0"                  # the pythonfmu whose wrapper the patches reproduce
SDIST = ("pythonfmu", "0.6.9",         # the last sdist with the wrapper's sources
         "13eab981d3c86704ab19b35ebcee9347b2dcc378bbe8d0b43c9ae1fe35bc9fa7")
WRAPPER_SOURCES = "pythonfmu/pythonfmu-export"        # inside the sdist's top folder
LIMITED_API = "0x030B0000"             # Python's stable ABI as of 3.11 (requires-python)


class WrapperUnavailable(Exception):
    """The corrected wrapper cannot be built here (the message says why)."""


def _sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _sdist(folder):
    """The pinned pythonfmu sdist: $FACEFMU_PYTHONFMU_SDIST, the cached copy, or pip
    download from the package index; its sha256 checked."""
    name, version, sha = SDIST
    path = Path(os.environ.get("FACEFMU_PYTHONFMU_SDIST") or
                folder / f"{name}-{version}.tar.gz")
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            run = subprocess.run(
                [sys.executable, "-m", "pip", "download", "--no-deps", "--no-binary",
                 ":all:", "--disable-pip-version-check", "-d", tmp, f"{name}=={version}"],
                capture_output=True, text=True)
            got = Path(tmp) / path.name
            if run.returncode != 0 or not got.is_file():
                raise WrapperUnavailable(f"cannot download the {name} {version} sdist: "
                                         + (run.stderr.strip().splitlines() or ["?"])[-1])
            os.replace(got, path)
    if _sha256(path) != sha:
        raise WrapperUnavailable(f"{path}: sha256 {_sha256(path)}, expected {sha}")
    return path


def apply_patch(text, root):
    """Apply a unified diff (paths a/... b/... relative to root) to the files under root
    with `git apply`, strictly (no fuzz: every hunk's context must match); ValueError with
    git's message where a hunk does not apply (nothing is then changed)."""
    git = shutil.which("git")
    if git is None:
        raise ValueError("git is needed to apply the wrapper's patches")
    run = subprocess.run([git, "apply", "--whitespace=nowarn", "-"], input=text, text=True,
                         cwd=root, capture_output=True)
    if run.returncode != 0:
        raise ValueError(run.stderr.strip() or f"git apply failed ({run.returncode})")


def _compiler():
    for cxx in (os.environ.get("CXX"), "c++", "g++", "clang++"):
        if cxx and shutil.which(cxx.split()[0]):
            return cxx.split()
    raise WrapperUnavailable("no C++ compiler (set CXX, or install g++)")


def patched_wrapper():
    """The corrected libpythonfmu-export.so for this machine's Python (built and cached on
    first use); WrapperUnavailable says why there is none."""
    import pythonfmu
    if not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")):
        raise WrapperUnavailable(f"the patches are for linux64 (this is {sys.platform} "
                                 f"{platform.machine()})")
    if pythonfmu.__version__ != WRAPPER_FOR:
        raise WrapperUnavailable(f"pythonfmu {pythonfmu.__version__} is installed; the "
                                 f"corrected wrapper is pythonfmu {WRAPPER_FOR}'s")
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        raise WrapperUnavailable(f"no Python headers ({include / 'Python.h'}; on Debian or "
                                 "Ubuntu: apt install python3-dev)")
    cxx = _compiler()
    patches = sorted(PATCHES.glob("*.patch"))
    version = subprocess.run([*cxx, "--version"], capture_output=True, text=True).stdout
    key = hashlib.sha256("\0".join(
        [SDIST[2], LIMITED_API, str(include), " ".join(cxx), version]
        + [p.read_text() for p in patches]).encode()).hexdigest()[:16]
    cache = user_cache_dir() / "pythonfmu-wrapper"
    out = cache / key / "libpythonfmu-export.so"
    if out.is_file():
        return out
    sdist = _sdist(cache)
    with tempfile.TemporaryDirectory(prefix="facefmu-wrapper-") as tmp:
        tmp = Path(tmp)
        top = f"{SDIST[0]}-{SDIST[1]}/"
        with tarfile.open(sdist) as tar:
            members = [m for m in tar.getmembers() if m.isfile() and
                       m.name.startswith(top + WRAPPER_SOURCES + "/")]
            for m in members:
                dest = tmp / m.name[len(top):]
                dest.parent.mkdir(parents=True, exist_ok=True)
                dest.write_bytes(tar.extractfile(m).read())
        for patch in patches:
            try:
                apply_patch(patch.read_text(), tmp)
            except (ValueError, OSError) as exc:
                raise WrapperUnavailable(f"{patch.name}: {exc}") from exc
        src = tmp / WRAPPER_SOURCES / "src"
        built = tmp / "libpythonfmu-export.so"
        cmd = [*cxx, "-std=c++17", "-O2", "-fPIC", "-shared", "-DNDEBUG",
               f"-DPy_LIMITED_API={LIMITED_API}", "-I", str(src), "-I", str(include),
               str(src / "pythonfmu" / "fmi2.cpp"), str(src / "pythonfmu" / "PySlaveInstance.cpp"),
               "-o", str(built)]
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            raise WrapperUnavailable("the wrapper did not compile:\n" + run.stderr[-3000:])
        out.parent.mkdir(parents=True, exist_ok=True)
        part = out.with_suffix(f".{os.getpid()}.part")
        shutil.copy2(built, part)
        os.replace(part, out)                       # atomic: parallel builds may race
    return out


def replace_wrapper(fmu, wrapper):
    """Put wrapper in place of the FMU's linux64 binary (rewrites the zip)."""
    fmu = Path(fmu)
    part = fmu.with_suffix(".fmu.part")
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(part, "w") as dst:
        names = [n for n in src.namelist() if n.startswith("binaries/linux64/")
                 and n.endswith(".so")]
        if len(names) != 1:
            raise SystemExit(f"{fmu}: expected one linux64 binary, found {names}")
        for info in src.infolist():
            if info.filename == names[0]:
                dst.write(wrapper, info.filename, compress_type=info.compress_type)
            else:
                dst.writestr(info, src.read(info.filename))
    os.replace(part, fmu)
