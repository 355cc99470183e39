% Reads the PVF and BDI fixtures with Bonn's btflib and compares its decoded values
% with expected_pvf_bdi.json (docs/formats/ubo.md, "How this was checked").
%
% Run from the repository root with GNU Octave (checked with 7.3) and a checkout of
% btflib whose @btf/private/*.m files are also copied into @btf (Octave does not call
% a class's private functions with the obj.f(...) form btflib uses):
%   octave-cli --eval "addpath('BTFLIB/matlab'); run('tests/reference/ubo/btflib_values.m')"
%
% btflib's `halfprecision` is a compiled MEX file; the function below replaces it with
% the IEEE 754 half-to-single decoding, the only conversion the readers use.
1;

function out = halfprecision(in, ~)
  in = uint32(in);
  s = bitshift(in, -15);
  e = double(bitand(bitshift(in, -10), 31));
  m = double(bitand(in, 1023));
  out = zeros(size(in), 'single');
  normal = e > 0 & e < 31;
  out(normal) = single(2 .^ (e(normal) - 15) .* (1 + m(normal) / 1024));
  sub = e == 0;
  out(sub) = single(2 ^ -14 * m(sub) / 1024);
  out(e == 31 & m == 0) = Inf;
  out(e == 31 & m > 0) = NaN;
  out(s == 1) = -out(s == 1);
end

% btf.read also prepares angular interpolation (init_dirs) with two functions Octave
% lacks; decode_abrdf does not use what they make, so simple stand-ins do.
function idx = knnsearch(X, Y, varargin)
  idx = zeros(size(Y, 1), 1);
  for i = 1 : size(Y, 1)
    [~, idx(i)] = min(sum((X - Y(i, :)) .^ 2, 2));
  end
end

function t = delaunayTriangulation(P)
  t = struct('Points', P);
end

here = fileparts(mfilename('fullpath'));
expected = jsondecode(fileread(fullfile(here, 'expected_pvf_bdi.json')));
% pvf_old.btf is left out: btflib parses the old PVF layout but its decoder then needs
% meta-data fields (num_channels, cosine_flag) that layout does not set.
names = {'pvf_texels.btf', 'pvf_lights.btf', 'bdi_full.btf', 'bdi_sparse.btf'};
worst = 0;
for n = 1 : numel(names)
  % Octave's `which`, called by btf.read on the name, fails on a name with a dot.
  plain = fullfile(tempdir(), strrep(names{n}, '.', '_'));
  copyfile(fullfile(here, names{n}), plain);
  b = btf(plain);
  want = expected.(matlab.lang.makeValidName(names{n}));
  % jsondecode gives want(l, v, y, x, c)
  for x = 1 : b.width()
    for y = 1 : b.height()
      a = b.decode_abrdf(x, y);  % nL x nV x nC
      for l = 1 : b.nL()
        for v = 1 : b.nV()
          for c = 1 : 3
            w = want(l, v, y, x, c);
            d = abs(double(a(l, v, c)) - w) / max(abs(w), 1);
            worst = max(worst, d);
            if d > 1e-6
              error('%s: x %d y %d light %d view %d channel %d: btflib %g, expected %g', ...
                names{n}, x, y, l, v, c, a(l, v, c), w);
            end
          end
        end
      end
    end
  end
  printf('%s: btflib agrees\n', names{n});
end
printf('largest relative difference %g\n', worst);
