"""The package itself: what `help` shows, the error classes, the version."""

import pydoc

import stereotac


def test_help_is_useful():
    text = pydoc.render_doc(stereotac, renderer=pydoc.plaintext)
    for words in ("TactileModel", "StereoRig", "reconstruct", "BadInputError", "load_rgb"):
        assert words in text
    assert stereotac.TactileModel.reconstruct.__doc__
    assert stereotac.StereoRig.load.__doc__


def test_error_classes():
    for kind, builtin in [
        (stereotac.BadInputError, ValueError),
        (stereotac.IoError, OSError),
        (stereotac.DeviceError, Exception),
    ]:
        assert issubclass(kind, stereotac.StereotacError), kind
        assert issubclass(kind, builtin), kind


def test_version():
    assert stereotac.__version__.count(".") == 2
