"""Bad input refused before anything runs, with one line naming it (issue 17, item 8): the
machine file ``run --core`` would have ignored, a binary teach-in file, ``--jobs 0``, and a Dask
scheduler on another host without TLS."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from turning_force.cli import main

FIG8 = str(Path(__file__).resolve().parents[2] / 'config' / 'experiments' / 'park1998_fig8.yaml')


def one_line(capfd) -> str:
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if not line.startswith('[')]   # node logs
    assert len(lines) == 1 and 'Traceback' not in err, err
    return lines[0]


def test_run_core_refuses_the_machine_file_the_graph_refuses(tmp_path, capfd):
    # On 3638a43 `run --core` ran with a machine file that was not YAML at all.
    machine = tmp_path / 'machine.yaml'
    machine.write_text('just a line of text, not a machine\n')
    sets = ['--set', f'pmc_bridge.machine_file={machine}']
    said = []
    for mode in (['--core'], ['--core', '--out', str(tmp_path / 'core')],
                 ['--out', str(tmp_path / 'graph')]):
        assert main(['run', FIG8, *mode, *sets]) == 2
        said.append(one_line(capfd))
    assert said == [f'turning-force: {machine}: expected a mapping, got str'] * 3
    assert not (tmp_path / 'core').exists() and not (tmp_path / 'graph').exists()


@pytest.mark.parametrize('mode', [['--core'], ['--out', 'graph']], ids=['core', 'graph'])
def test_a_binary_teach_file_is_one_line(tmp_path, capfd, mode, monkeypatch):
    # On 3638a43: a UnicodeDecodeError traceback.
    monkeypatch.chdir(tmp_path)
    teach = tmp_path / 'teach.yaml'
    teach.write_bytes(bytes(range(256)) * 4)
    assert main(['run', FIG8, *mode, '--set', f'pmc_bridge.teach_file={teach}',
                 '--set', 'pmc_bridge.tool=T0101']) == 2
    assert one_line(capfd) == (f'turning-force: {teach}: pmc_bridge.teach_file: not a text '
                               '(UTF-8) teach-in file (byte 128 of it)')


def test_replay_jobs_zero_is_refused(reference_bag, capfd):
    # On 3638a43 accepted.
    assert main(['replay', str(reference_bag), str(reference_bag), '--jobs', '0']) == 2
    assert one_line(capfd) == 'turning-force: --jobs 0: need at least 1'


REMOTE = 'tcp://192.0.2.7:8786'   # TEST-NET-1: never a host (nothing is sent: refused first)


@pytest.mark.parametrize('command', ['sweep', 'replay'])
def test_a_remote_scheduler_without_tls_is_refused(reference_bag, capfd, command):
    # On 3638a43 any tcp:// scheduler was taken, without TLS and without a word.
    argv = (['sweep', FIG8, '--grid', 'force_controller.smc_eta=0.1,0.2'] if command == 'sweep'
            else ['replay', str(reference_bag)])
    assert main([*argv, '--dask', REMOTE]) == 2
    assert one_line(capfd) == (
        f'turning-force: --dask {REMOTE}: a scheduler on another host without TLS (anyone on '
        'the network could read the sessions and run code on the workers): give a tls:// '
        'address with --tls-ca, --tls-cert and --tls-key, or --insecure on a network you trust')


def test_tls_needs_its_three_files_and_they_need_tls(reference_bag, capfd, tmp_path):
    assert main(['replay', str(reference_bag), '--dask', 'tls://192.0.2.7:8786']) == 2
    assert one_line(capfd) == ('turning-force: --dask tls://192.0.2.7:8786: tls:// needs '
                               '--tls-ca, --tls-cert and --tls-key')
    pem = tmp_path / 'ca.pem'
    pem.write_text('not used')
    assert main(['replay', str(reference_bag), '--dask', REMOTE, '--insecure', '--tls-ca',
                 str(pem), '--tls-cert', str(pem), '--tls-key', str(pem)]) == 2
    assert one_line(capfd) == (f'turning-force: --dask {REMOTE}: --tls-ca, --tls-cert and '
                               '--tls-key are for a tls:// address')
    assert main(['replay', str(reference_bag), '--insecure']) == 2
    assert one_line(capfd) == ('turning-force: --tls-ca, --tls-cert, --tls-key and --insecure '
                               'go with --dask')


def test_a_local_scheduler_over_tcp_is_taken(dask_cluster, reference_bag, capfd):
    # The LocalCluster on 127.0.0.1: no TLS needed on this machine.
    address = dask_cluster.scheduler_address
    assert address.startswith('tcp://127.0.0.1:')
    assert main(['replay', str(reference_bag), '--dask', address]) == 0
    assert '1200 blocks replayed open loop' in capfd.readouterr().out


def certificates(folder: Path) -> tuple[Path, Path, Path]:
    """A CA and a certificate and key it signed for 127.0.0.1 (openssl), in ``folder``."""
    ca, ca_key = folder / 'ca.pem', folder / 'ca.key'
    cert, key, request = folder / 'node.pem', folder / 'node.key', folder / 'node.csr'
    extension = folder / 'san.cnf'
    extension.write_text('subjectAltName = IP:127.0.0.1\n')
    for argv in (
            ['req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-keyout', ca_key, '-out', ca,
             '-days', '2', '-subj', '/CN=turning_force test CA'],
            ['req', '-newkey', 'rsa:2048', '-nodes', '-keyout', key, '-out', request,
             '-subj', '/CN=127.0.0.1'],
            ['x509', '-req', '-in', request, '-CA', ca, '-CAkey', ca_key, '-CAcreateserial',
             '-out', cert, '-days', '2', '-extfile', extension]):
        subprocess.run(['openssl', *map(str, argv)], check=True, capture_output=True,
                       timeout=60)
    return ca, cert, key


def test_a_scheduler_over_tls_is_reached_with_its_certificates(reference_bag, tmp_path, capfd):
    # distributed's own Security carries the certificates: a LocalCluster that takes only TLS.
    from distributed import LocalCluster
    from distributed.security import Security

    ca, cert, key = certificates(tmp_path)
    security = Security(tls_ca_file=str(ca), tls_scheduler_cert=str(cert),
                        tls_scheduler_key=str(key), tls_worker_cert=str(cert),
                        tls_worker_key=str(key), tls_client_cert=str(cert),
                        tls_client_key=str(key), require_encryption=True)
    with LocalCluster(host='127.0.0.1', protocol='tls://', security=security, n_workers=1,
                      threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        address = cluster.scheduler_address
        assert address.startswith('tls://127.0.0.1:')
        assert main(['replay', str(reference_bag), '--dask', address, '--tls-ca', str(ca),
                     '--tls-cert', str(cert), '--tls-key', str(key)]) == 0
        assert '1200 blocks replayed open loop' in capfd.readouterr().out
