function mpc = kundur_two_area
%KUNDUR_TWO_AREA  Kundur's two-area, four-machine system (11 buses), MATPOWER format.
%   Source: P. Kundur, "Power System Stability and Control", McGraw-Hill 1994,
%   Example 12.6 (the two-area system of section 12.8, Fig. E12.8), typed from its data:
%   - generators: 900 MVA, 20 kV; G1 P=700 MW Et=1.03, G2 P=700 MW Et=1.01,
%     G3 P=719 MW Et=1.03 (the swing machine, angle -6.8 deg), G4 P=700 MW Et=1.01;
%   - step-up transformers 20/230 kV, 900 MVA, impedance 0 + j0.15 pu on 900 MVA
%     (here j0.15/9 on the 100 MVA system base);
%   - 230 kV lines, per km on 100 MVA / 230 kV: r = 0.0001, xL = 0.001, bC = 0.00175 pu;
%     lengths 5-6: 25 km, 6-7: 10 km, 7-8: 110 km (two circuits), 8-9: 110 km
%     (two circuits), 9-10: 10 km, 10-11: 25 km;
%   - loads (constant impedance in this project): bus 7 P=967 MW, Q=100 MVAr,
%     shunt capacitor 200 MVAr; bus 9 P=1767 MW, Q=100 MVAr, capacitor 350 MVAr.
%   Bus numbering as in Kundur's figure: G1..G4 at buses 1..4, lines between 5..11.
%   Machine (dynamic) data in kundur_two_area_machines.csv.

%% system MVA base
mpc.version = '2';
mpc.baseMVA = 100;

%% bus data
%	bus_i	type	Pd	Qd	Gs	Bs	area	Vm	Va	baseKV	zone	Vmax	Vmin
mpc.bus = [
	1	2	0	0	0	0	1	1.03	20.2	20	1	1.1	0.9;
	2	2	0	0	0	0	1	1.01	10.5	20	1	1.1	0.9;
	3	3	0	0	0	0	2	1.03	-6.8	20	1	1.1	0.9;
	4	2	0	0	0	0	2	1.01	-17.0	20	1	1.1	0.9;
	5	1	0	0	0	0	1	1	0	230	1	1.1	0.9;
	6	1	0	0	0	0	1	1	0	230	1	1.1	0.9;
	7	1	967	100	0	200	1	1	0	230	1	1.1	0.9;
	8	1	0	0	0	0	1	1	0	230	1	1.1	0.9;
	9	1	1767	100	0	350	2	1	0	230	1	1.1	0.9;
	10	1	0	0	0	0	2	1	0	230	1	1.1	0.9;
	11	1	0	0	0	0	2	1	0	230	1	1.1	0.9;
];

%% generator data
%	bus	Pg	Qg	Qmax	Qmin	Vg	mBase	status	Pmax	Pmin
mpc.gen = [
	1	700	185	9999	-9999	1.03	900	1	900	0;
	2	700	235	9999	-9999	1.01	900	1	900	0;
	3	719	176	9999	-9999	1.03	900	1	900	0;
	4	700	202	9999	-9999	1.01	900	1	900	0;
];

%% branch data
%	fbus	tbus	r	x	b	rateA	rateB	rateC	ratio	angle	status	angmin	angmax
mpc.branch = [
	1	5	0	0.0166666666666667	0	0	0	0	1	0	1	-360	360;
	2	6	0	0.0166666666666667	0	0	0	0	1	0	1	-360	360;
	3	11	0	0.0166666666666667	0	0	0	0	1	0	1	-360	360;
	4	10	0	0.0166666666666667	0	0	0	0	1	0	1	-360	360;
	5	6	0.0025	0.025	0.04375	0	0	0	0	0	1	-360	360;
	6	7	0.001	0.01	0.0175	0	0	0	0	0	1	-360	360;
	7	8	0.011	0.11	0.1925	0	0	0	0	0	1	-360	360;
	7	8	0.011	0.11	0.1925	0	0	0	0	0	1	-360	360;
	8	9	0.011	0.11	0.1925	0	0	0	0	0	1	-360	360;
	8	9	0.011	0.11	0.1925	0	0	0	0	0	1	-360	360;
	9	10	0.001	0.01	0.0175	0	0	0	0	0	1	-360	360;
	10	11	0.0025	0.025	0.04375	0	0	0	0	0	1	-360	360;
];
