# Sourced first by a device script of the lab log (studies/performance/log/*/run.sh), from the repository root
# on the lent GPU machine:
# its image has torch but no TorchRL, so TorchRL, tensordict and their pure-Python needs are installed from the
# cp312 wheels carried in .gpu/c2/whl (run's carry), and put on PYTHONPATH with src/. No SUMO: the scripts that
# source this need none.
set -u
export PYTHONUNBUFFERED=1
S=/root/g/site
mkdir -p $S
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target $S .gpu/c2/whl/*.whl || exit 3
export PYTHONPATH=$PWD/src:$S
nvidia-smi -L
