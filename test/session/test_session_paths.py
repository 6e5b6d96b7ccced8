"""A session folder reads and rewrites only its own files (issue 17, U8): a ``metadata.yaml``
that names a file outside the folder (``../``, an absolute path) is refused by ``report`` and
``repair`` with one line, a second .mcap is refused, a garbled ``metadata.yaml`` is one line
(not a Python repr), and ``repair`` keeps a copy of every file it replaces."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from bagfaults import REFERENCE, copy_reference, mcap_of, truncate
from turning_force.cli import main
from turning_force.session.reader import read_session


def one_line(capfd) -> str:
    err = capfd.readouterr().err
    assert err.count('\n') == 1 and 'Traceback' not in err, err
    return err.strip()


def naming(bag: Path, name: str) -> Path:
    """The session's metadata.yaml made to name ``name`` as its file."""
    metadata = bag / 'metadata.yaml'
    info = yaml.safe_load(metadata.read_text())
    info['rosbag2_bagfile_information']['relative_file_paths'] = [name]
    metadata.write_text(yaml.safe_dump(info))
    return bag


@pytest.mark.parametrize('where', ['parent', 'absolute'])
def test_a_file_named_outside_the_folder_is_refused_and_left_alone(tmp_path, capfd, where):
    # On 3638a43, repair renamed ../outside.mcap to outside.mcap.damaged, and report read it.
    bag = copy_reference(tmp_path / 'session')
    outside = tmp_path / 'outside.mcap'
    shutil.copy(mcap_of(bag), outside)
    before = outside.read_bytes()
    name = '../outside.mcap' if where == 'parent' else str(outside)
    naming(bag, name)
    for command in (['report', str(bag), '--out', str(tmp_path / 'r.png')], ['repair', str(bag)]):
        assert main(command) == 2
        assert one_line(capfd) == (
            f'turning-force: {bag}: metadata.yaml names {name!r}, which is not a file in the '
            'session folder: refused (a session reads and rewrites only its own files)')
    assert outside.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['outside.mcap', 'session']
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'park1998_fig8.mcap']


def test_a_second_mcap_in_the_folder_is_refused(tmp_path, capfd):
    # On 3638a43 the second file was ignored without a word.
    bag = copy_reference(tmp_path / 'two')
    shutil.copy(mcap_of(bag), bag / 'other.mcap')
    for command in (['report', str(bag), '--out', str(tmp_path / 'r.png')], ['repair', str(bag)]):
        assert main(command) == 2
        assert one_line(capfd) == (
            f'turning-force: {bag}: park1998_fig8.mcap, other.mcap: more than one .mcap in the '
            'session folder; a session is one .mcap (move the others out)')


@pytest.mark.parametrize('garbage', [b'\x89\x00\xff' * 2000, b'{{{ [[[ :\n' * 500,
                                     b'- just\n- a list\n' * 400],
                         ids=['binary', 'not-yaml', 'a-list'])
def test_a_garbled_metadata_file_is_one_short_line_and_repair_keeps_it(tmp_path, capfd,
                                                                      garbage):
    # On 3638a43 this printed the exception's repr (the whole value) and repair overwrote the
    # file without a copy.
    bag = copy_reference(tmp_path / 'garbled')
    (bag / 'metadata.yaml').write_bytes(garbage)
    assert main(['report', str(bag), '--out', str(tmp_path / 'r.png')]) == 2
    line = one_line(capfd)
    assert line.startswith(f'turning-force: {bag / "metadata.yaml"}: not rosbag2 metadata: ')
    assert len(line) < len(str(bag)) + 200, line
    assert main(['repair', str(bag)]) == 0   # rebuilt from what the MCAP holds
    capfd.readouterr()
    assert (bag / 'metadata.yaml.before_repair').read_bytes() == garbage
    assert len(read_session(bag).blocks) == 1200


def test_repair_never_overwrites_what_an_earlier_repair_kept(tmp_path):
    # Named as its file is: the repaired file has the same name as the one it replaces.
    bag = truncate(copy_reference(tmp_path / 'park1998_fig8'), 0.99)
    first = mcap_of(bag).read_bytes()
    assert main(['repair', str(bag)]) == 0
    truncate(bag, 0.9)
    second = mcap_of(bag).read_bytes()
    assert main(['repair', str(bag)]) == 0
    assert (bag / 'park1998_fig8.mcap.damaged').read_bytes() == first
    assert (bag / 'park1998_fig8.mcap.damaged.2').read_bytes() == second
    assert (bag / 'metadata.yaml.before_repair').read_text() == \
        (REFERENCE / 'metadata.yaml').read_text()
    assert (bag / 'metadata.yaml.before_repair.2').is_file()
