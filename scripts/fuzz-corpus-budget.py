"""Trims a fuzz target's corpus to a byte budget, keeping coverage.

usage: python3 scripts/fuzz-corpus-budget.py TARGET BUDGET_BYTES   (after `cargo +nightly fuzz build`)

Runs the target's libFuzzer binary in merge mode over fuzz/corpus/TARGET (it processes the inputs
smallest first and records, per input, the edges it adds), then keeps the seeds and each input that
adds an edge until BUDGET_BYTES are spent; the rest of the directory is deleted. Prints the kept
files and bytes, and the edges kept of the corpus's whole.
"""
import sys, os, subprocess, tempfile
t = sys.argv[1]
root = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'fuzz')
corpus = f'{root}/corpus/{t}'
binary = f'{root}/target/x86_64-unknown-linux-gnu/release/{t}'
ctl = f'/tmp/mcf-{t}'
empty = tempfile.mkdtemp()
if os.path.exists(ctl): os.remove(ctl)
subprocess.run(['nice','-n','19',binary,'-merge=1',f'-merge_control_file={ctl}','-timeout=30',empty,corpus],stdout=subprocess.DEVNULL,stderr=subprocess.DEVNULL)
lines = open(ctl).read().split('\n')
n = int(lines[0]); files = lines[2:2+n]
cov = {}
for l in lines[2+n:]:
    p = l.split()
    if len(p) >= 2 and p[0] == 'COV':
        cov[int(p[1])] = set(p[2:])
order = sorted(cov, key=lambda i: os.path.getsize(files[i]))
covered = set(); keep = []
# seeds first
for i in order:
    if os.path.basename(files[i]).startswith('seed-'):
        keep.append(i); covered |= cov[i]
budget = int(sys.argv[2]) if len(sys.argv) > 2 else 10**9
total_edges = set().union(*cov.values()) if cov else set()
size = sum(os.path.getsize(files[i]) for i in keep)
for i in order:
    if i in keep: continue
    new = cov[i] - covered
    if new and size + os.path.getsize(files[i]) <= budget:
        keep.append(i); covered |= new; size += os.path.getsize(files[i])
keepset = {files[i] for i in keep}
for f in os.listdir(corpus):
    p = os.path.join(corpus, f)
    if p not in keepset: os.remove(p)
print(f'| {t} | {len(keep)} / {size} | {len(covered)} of {len(total_edges)} |')
